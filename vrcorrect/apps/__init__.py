"""Layer 6, every entry point: the ``vrcorrect`` command line (``cli``) and one module per
command or family of commands. Nothing below this layer imports it."""
