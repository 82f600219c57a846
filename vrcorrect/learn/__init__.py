"""Layer 4: the learned correction (issue 5) - data set, U-Net, training.

* :mod:`vrcorrect.learn.conditioning` - prescription ranges, the eye's conditioning vector and
  the pre-correction channels (numpy only: the runtime imports it).
* :mod:`vrcorrect.learn.dataset` - crops, sampled eyes and ``fast``'s corrections, in ``.npz``
  shards with a JSON manifest; resumable, parallel on local processes.
* :mod:`vrcorrect.learn.model` - the conditioned U-Net (torch).
* :mod:`vrcorrect.learn.train` - training (torch): loss through the eye's kernel, checkpoints,
  CSV log, resumable.
* :mod:`vrcorrect.learn.unrolled` - the unrolled ADMM correction (torch; issue 25): ``fast``'s
  exact per-frequency data step with the eye's kernel bank as input, stage settings from the eye, a
  small learned prior; untrained, it is ``fast``'s ADMM itself.
* :mod:`vrcorrect.learn.export` - ONNX export checked against torch (``tools/export_onnx.py``);
  :mod:`vrcorrect.runtime.learned` runs the exported model without torch.

The commands ``vrcorrect dataset`` and ``vrcorrect train`` are in :mod:`vrcorrect.apps.learning`
(layer 7).

Importing this package imports neither torch nor the submodules.
"""
