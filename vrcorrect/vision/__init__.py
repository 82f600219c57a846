"""Layer 3, what the eye sees and how good it is: the forward model (``forward``), the
perceptual and numerical scores (``metrics``) and simulated letter acuity (``acuity``)."""
