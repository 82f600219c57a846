"""Layer 0, plumbing every layer may use: typed errors (``errors``), safe file writing
(``fileio``), image decoding and encoding (``imageio``) and the bundled test charts (``charts``)."""
