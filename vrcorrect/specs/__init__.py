"""Layer 1, what the user and the hardware are, as plain validated data: the eye's
prescription (``prescription``) and the display's profile (``display``), with the checks their
validators share (``validation``), and the names they and every layer above share: eyes, backends,
filters, methods, precisions and the iterations-per-frame range (``vocabulary``)."""
