"""Layer 5: the real-time library (GLSL and onnxruntime backends, the moderngl pipeline, the
windows and the OpenXR session). A library, not an application: the commands that run it are in
:mod:`vrcorrect.apps`.

Modules here may import layers 0-4 but never torch (docs/architecture.md, 'Layers': the render
loop needs numpy, moderngl, glfw, onnxruntime, pyopenxr), and never
:mod:`vrcorrect.solvers.iterative`; ``tests/test_layers.py`` enforces both.

Three packages, with a rule between them (``tests/test_layers.py``):
  * the plugin, this folder's own modules (below): the correction, GL and its caches. It imports
    neither of the others.
  * ``shell`` - the applications' loops: the window, the mirror, the overlay, the headset app, the
    picture feeds, the demo scene, the text, headless rendering.
  * ``layer`` - the OpenXR API layer's engine and its build.
  The shell and the layer never import each other.

The correction
  * ``corrector`` - :class:`Corrector`, the one owner of an eye's state: prescription (read once,
    hot-reloaded), live offsets, the per-size GPU resources and the warm start.
  * ``eye_model`` - what the CPU prepares for an eye (kernel, regulariser, filters) per backend.
  * ``fft``, ``filters`` - the GPU FFT bank and the separable filter bank.
  * ``learned``, ``onnx_backend``, ``model_path`` - the learned model on onnxruntime; ``unrolled`` -
    the unrolled model on onnxruntime.
  * ``motion`` - reprojection of the warm start (head pose, phase correlation).
  * ``strategies`` - one frame's passes per backend and filter (ADMM, FISTA, one pass, foveated,
    ONNX); ``dispatch`` - the GPU's passes and their costs; ``budget`` - the frame budget;
    ``pupil_bank`` - the kernel banks of pupils and the pupil that follows the light;
    ``eye_source`` - the prescription's worker (file, stamp, offsets).
GL and shaders
  * ``gl`` - contexts (headless EGL), GL error checks, textures with the one place that handles
    OpenGL's bottom-up rows; ``shaders`` - the GLSL loader (``shaders/``), text only.
  * ``glcache`` - GL contexts for building off an application's frame: a loader that caches
    compiled programs between runs (``glGetProgramBinary``) and lets other threads run during long
    GL calls; the layer's EGL contexts and GLX contexts shared with an application's.
  * ``eye_cache`` - designed eye models kept between runs (the layer's second launch).
  * ``optional`` - the optional dependencies (moderngl, glfw, pyopenxr, mss), imported on first
    use with one message naming the extra to install.
  * ``gaze`` - the gaze's direction in a view (the headset app's and the layer's eye tracker).
Importing this package imports neither moderngl nor glfw; the submodules that need them do.
"""
