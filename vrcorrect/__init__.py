"""vrcorrect: pre-correct what a display shows so that an eye that needs glasses sees it sharp.

The package is a stack of layers, one folder each (lowest first). A module imports only from
its own folder or from lower layers (``learn`` may use ``solvers`` beside it), and nothing on
the real-time path imports torch; ``tests/test_layers.py`` reads the layers from these folders'
docstrings and enforces both (docs/architecture.md, 'Layers').

0. ``plumbing``: errors, safe file output, image I/O, image sets, test charts
1. ``specs``: the eye's prescription and the display's profile, validated data
2. ``physics``: optics (Zernike wavefront, PSF), perception (cones), the per-eye kernel
3. ``vision``: the forward model (what the eye sees), metrics, simulated acuity
4. ``solvers`` (numpy first, torch only for autograd) and ``learn`` (U-Net, data set, training)
5. ``runtime``: the real-time library (Corrector, GLSL and ONNX backends, window, sources, OpenXR)
6. ``studies``: the evaluation, simulated acuity with corrections, the benchmarks and their plots
7. ``apps``: every entry point (the CLI, one module per command: parse, call, print)
"""

__version__ = "0.1.0"
