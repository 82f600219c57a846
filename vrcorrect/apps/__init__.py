"""Layer 7, every entry point: the ``vrcorrect`` command line (``cli``) and one module per
command or family of commands (each with its ``add_parser`` and ``cmd_*``: it parses arguments,
calls the layers below and prints), and their shared options (``common``, ``realtime_options``,
``clips``). What the evaluation, acuity and bench commands measure is :mod:`vrcorrect.studies`.
Nothing below this layer imports it.

Every run of ``vrcorrect`` imports every command module to build its parser, so a command module
imports the physics, solvers, metrics and training stacks (scipy, colour-science, torch) inside
the command that uses them, marked "on use: start-up time"; ``tests/test_layers.py`` checks that
building the parser loads none of them.
"""
