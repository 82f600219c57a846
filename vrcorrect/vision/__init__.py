"""Layer 3, what the eye sees and how good it is: the forward model (``forward``), the
perceptual and numerical scores (``metrics``; ColorVideoVDP and FovVideoVDP in ``vdp``, the
checks of their inputs in ``metric_checks``) and simulated letter acuity (``acuity``; the Sloan
letters it draws in ``sloan``)."""
