"""Layer 5: the real-time library (GLSL and onnxruntime backends, the moderngl pipeline, the
windows and the OpenXR session). A library, not an application: the commands that run it are in
:mod:`vrcorrect.apps`.

Modules here may import layers 0-4 but never torch (docs/architecture.md, 'Layers': the render
loop needs numpy, moderngl, glfw, onnxruntime, pyopenxr), and never
:mod:`vrcorrect.solvers.iterative`; ``tests/test_layers.py`` enforces both.

The correction
  * ``corrector`` - :class:`Corrector`, the one owner of an eye's state: prescription (read once,
    hot-reloaded), live offsets, the per-size GPU resources and the warm start.
  * ``eye_model`` - what the CPU prepares for an eye (kernel, regulariser, filters) per backend.
  * ``fft``, ``filters`` - the GPU FFT bank and the separable filter bank.
  * ``learned``, ``onnx_backend``, ``model_path`` - the learned model on onnxruntime; ``unrolled`` -
    the unrolled model on onnxruntime.
  * ``motion`` - reprojection of the warm start (head pose, phase correlation).
  * ``render`` - one image through the pipeline, headless (``vrcorrect render``).
GL and shaders
  * ``gl`` - contexts (headless EGL), GL error checks, textures with the one place that handles
    OpenGL's bottom-up rows; ``shaders`` - the GLSL loader (``shaders/``), text only.
  * ``glcache`` - GL contexts for building off an application's frame: a loader that caches
    compiled programs between runs (``glGetProgramBinary``) and lets other threads run during long
    GL calls; the layer's EGL contexts and GLX contexts shared with an application's.
  * ``eye_cache`` - designed eye models kept between runs (the layer's second launch).
What is shown and where
  * ``sources`` - picture sources (still, folder, animated, video, screen grab); ``scene`` - the
    3D demo scene; ``text`` - font atlas and text layout.
  * ``window`` - the window shell the apps share (optional imports, GLFW, sRGB check, stage
    times, screenshots); ``mirror``, ``overlay``, ``xr`` - the desktop mirror, the screen overlay
    and the OpenXR headset loop; ``xrlayer`` - the OpenXR API layer's engine, ``layer_build`` - its
    C shim (built into the package by ``setup.py``; compiled here only as a source checkout's
    fallback), its Python configuration and its loader manifest.

Importing this package imports neither moderngl nor glfw; the submodules that need them do.
"""
