"""The OpenXR API layer's Python side (layer 5, like the plugin):

* ``engine`` - what the C shim (``layer/``) calls each frame: the frame protocol and the
  Correctors' life; ``vulkan`` - its Vulkan half;
* ``config`` - the layer's configuration, environment, off switch and log;
* ``interop`` - swapchain formats, Vulkan memory and semaphores imported into GL, the shared chains;
* ``pipeline`` - both eyes' Correctors and the copy passes on a context of their own;
  ``builder`` - the worker that makes pipelines off the application's frame;
* ``build`` - the library built into this package by ``setup.py`` (compiled here only as a source
  checkout's fallback), its configuration file and its loader manifest.

It imports the plugin (``vrcorrect.runtime``) and never the shells (``vrcorrect.runtime.shell``),
which never import it: ``tests/test_layers.py`` checks both.
"""
