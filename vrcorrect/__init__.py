"""vrcorrect: pre-correct what a display shows so that an eye that needs glasses sees it sharp.

Layers (lowest first; a module imports only from layers below it, see DESIGN.md):

1. ``prescription``, ``display`` (plus ``errors``, ``fileio``, ``imageio``, ``charts``)
2. ``optics``, ``perception``, ``kernel``
3. ``forward``, ``metrics``
4. ``solvers``, ``learn`` (torch)
5. ``runtime`` (no torch)
6. ``cli`` (and its helpers ``demo``, ``plots``, ``bench``, ``bench_kernel``)
"""

__version__ = "0.1.0"
