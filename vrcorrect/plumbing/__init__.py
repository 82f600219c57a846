"""Layer 0, plumbing every layer may use: typed errors (``errors``), safe file writing
(``fileio``), image decoding and encoding (``imageio``), clips read frame by frame and written as
folders of frames (``clips``) and the bundled test charts (``charts``)."""
