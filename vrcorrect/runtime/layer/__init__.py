"""The OpenXR API layer's Python side (layer 5, like the plugin): ``engine`` - what the C shim
(``layer/``) calls each frame (its configuration, the Vulkan memory import, the GL state around the
plugin's :class:`~vrcorrect.runtime.corrector.Corrector`, the frame protocol); ``build`` - the
library built into this package by ``setup.py`` (compiled here only as a source checkout's
fallback), its configuration file and its loader manifest.

It imports the plugin (``vrcorrect.runtime``) and never the shells (``vrcorrect.runtime.shell``),
which never import it: ``tests/test_layers.py`` checks both.
"""
