"""The shells: the applications' side of the real-time library, each a loop around the plugin's
:class:`~vrcorrect.runtime.corrector.Corrector` (layer 5, like the plugin).

* ``window`` - the window shell the apps share (GLFW, the sRGB check, screenshots, the apps' base
  classes); ``keys`` - the keys they share (pure); ``timing`` - a frame's stage times; ``mirror``, ``overlay``, ``xr`` - the desktop mirror, the screen overlay and the OpenXR
  headset loop (a package: its session, views, instance, eye tracker and app).
* ``sources`` - picture feeds (still, folder, animated, video, screen grab), ``source_spec`` - what
  ``--source`` names, parsed before anything opens; ``scene`` - the 3D demo
  scene; ``text`` - font atlas and text layout.
* ``render`` - one image through the pipeline, headless (``vrcorrect render``).

The shells import the plugin (``vrcorrect.runtime``) and never the API layer
(``vrcorrect.runtime.layer``), which never imports them: ``tests/test_layers.py`` checks both.
"""
