"""Layer 5: the real-time path (GLSL and onnxruntime backends, the moderngl pipeline).

Modules here may import layers 0-4 but never torch (DESIGN.md: the render loop needs numpy,
moderngl, glfw, onnxruntime), and never :mod:`vrcorrect.solvers.iterative`;
``tests/test_layers.py`` enforces both.

* :mod:`vrcorrect.runtime.shaders` - the GLSL loader (``shaders/``: includes, defines,
  stages, ``#line`` mapping of compiler messages back to files); text only, no GL needed.
* :mod:`vrcorrect.runtime.gl` - contexts (headless EGL), GL error checks, the fullscreen
  triangle, texture upload/download with the one place that handles OpenGL's bottom-up rows.
* :mod:`vrcorrect.runtime.scene` - what the mirror shows each eye: the 3D demo scene, or an
  image, a folder of images, an animated image or a video, as eye textures of sRGB codes.
* :mod:`vrcorrect.runtime.mirror` - the desktop mirror window (``vrcorrect mirror``): both eyes
  side by side through their Correctors, keys as a pure state machine, a timing panel.

Importing this package imports neither moderngl nor glfw; the submodules that need them do.
"""
