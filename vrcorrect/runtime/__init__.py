"""Layer 5: the real-time path (GLSL and onnxruntime backends, the moderngl pipeline).

Modules here may import layers 0-4 but never torch (DESIGN.md: the render loop needs numpy,
moderngl, glfw, onnxruntime), and never :mod:`vrcorrect.solvers.iterative`;
``tests/test_layers.py`` enforces both.

* :mod:`vrcorrect.runtime.shaders` - the GLSL loader (``shaders/``: includes, defines,
  stages, ``#line`` mapping of compiler messages back to files); text only, no GL needed.
* :mod:`vrcorrect.runtime.gl` - contexts (headless EGL), GL error checks, the fullscreen
  triangle, texture upload/download with the one place that handles OpenGL's bottom-up rows.

Importing this package imports neither moderngl nor glfw; the submodules that need them do.
"""
