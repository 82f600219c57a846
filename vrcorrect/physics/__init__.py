"""Layer 2, the physics of seeing a display: the eye's optics (``zernike`` polynomials and
wavefronts, the refractive state in ``refraction``, the ``wave_psf`` and ``geometric_psf`` models
with ``disc_pixels``, ``sampling`` on the display's pixels, ``psf`` choosing between the models,
their ``options``), the cones and the display-to-LMS matrix (``perception``), and the per-eye blur
kernel that joins them (``kernel``, with its ``kernel_report``)."""
