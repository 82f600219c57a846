"""Layer 0, plumbing every layer may use: typed errors (``errors``), safe file writing
(``fileio``), image decoding and encoding (``imageio``), clips read frame by frame and written as
folders of frames (``clips``), the bundled test charts (``charts``) and a command's signals
(``signals``: SIGTERM, SIGHUP and Ctrl-C held out of imports and libraries' code)."""
