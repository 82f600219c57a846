"""Layer 1, what the user and the hardware are, as plain validated data: the eye's
prescription (``prescription``) and the display's profile (``display``), with the checks their
validators share (``validation``)."""
