"""Layer 2, the physics of seeing a display: the eye's wavefront and point-spread function
(``optics``), the cones and the display-to-LMS matrix (``perception``), and the per-eye blur
kernel that joins them (``kernel``)."""
