"""Layer 6, every entry point: the ``vrcorrect`` command line (``cli``) and one module per
command or family of commands (each with its ``add_parser`` and ``cmd_*``), the benches
(``bench/``) and their shared options (``common``, ``realtime_options``). Nothing below this layer
imports it.

Every run of ``vrcorrect`` imports every command module to build its parser, so a command module
imports the physics, solvers, metrics and training stacks (scipy, colour-science, torch) inside
the command that uses them, marked "on use: start-up time"; ``tests/test_layers.py`` checks that
building the parser loads none of them.
"""
