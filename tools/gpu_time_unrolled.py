"""Time the unrolled model's torch forward on a CUDA GPU (random inputs of the right shapes: the cost does not
depend on the values). Standalone: it loads vrcorrect/learn/unrolled.py with its few imports stubbed, so it
runs where only torch is installed (the lent GPU machine). Run from the checkout's root:
`python3 tools/gpu_time_unrolled.py` (CPU_CHECK=1: a tiny CPU run); writes $OUT/gpu_time.json."""
import importlib.util
import json
import os
import sys
import time
import types
import torch
for name in ("vrcorrect", "vrcorrect.learn", "vrcorrect.plumbing", "vrcorrect.solvers"):
    m = types.ModuleType(name); m.__path__ = []; sys.modules[name] = m
errs = types.ModuleType("vrcorrect.plumbing.errors")
class ValidationError(ValueError):
    def __init__(self, *a): super().__init__(str(a))
errs.ValidationError = ValidationError; sys.modules[errs.__name__] = errs
admm = types.ModuleType("vrcorrect.solvers.admm"); admm.FAST_RHO, admm.FAST_RELAXATION = 0.1, 1.8
sys.modules[admm.__name__] = admm
cond = types.ModuleType("vrcorrect.learn.conditioning"); cond.unrolled_spectra = None; sys.modules[cond.__name__] = cond
spec = importlib.util.spec_from_file_location("vrcorrect.learn.unrolled", os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "vrcorrect", "learn", "unrolled.py"))
U = importlib.util.module_from_spec(spec); sys.modules[spec.name] = U; spec.loader.exec_module(U)
CPU = os.environ.get("CPU_CHECK") == "1"
dev = torch.device("cpu" if CPU else "cuda")
sync = (lambda: None) if CPU else torch.cuda.synchronize
gpu = "cpu" if CPU else torch.cuda.get_device_name(0)
print(torch.__version__, gpu, flush=True)
out = {"torch": torch.__version__, "gpu": gpu, "runs": []}
for (H, W, P0, P1) in (((40, 40, 64, 64),) if CPU else ((256, 256, 512, 512), (1920, 1832, 2048, 2048))):
    F1 = P1 // 2 + 1
    g = torch.Generator().manual_seed(0)
    img = lambda: torch.rand(1, 3, H, W, generator=g).to(dev)
    spec_ = torch.randn(1, 3, 3, P0, F1, 2, generator=g).to(dev) * 0.1
    basis = torch.randn(1, 3, 3, P0, F1, 2, generator=g).to(dev) * 0.5
    lam = torch.rand(1, 3, P0, F1, generator=g).to(dev)
    norm2 = torch.tensor([1.0], device=dev); feats = torch.rand(1, 5, generator=g).to(dev)
    args = (img(), img(), spec_, basis, lam, norm2)
    d1, d2 = img(), img()
    for label, cfg in (("learned 8 stages, settings only", U.UnrolledConfig(stages=8, prior_width=0, features=5)),
                       ("twin 8 stages", U.UnrolledConfig(stages=8, prior_width=0, features=0)),
                       ("learned 16 stages, settings only", U.UnrolledConfig(stages=16, prior_width=0, features=5))):
        model = U.UnrolledADMM(cfg).to(dev).eval()
        kw = {"features": feats} if cfg.features else {}
        with torch.no_grad():
            for _ in range(3): model(*args, target=args[1], d1=d1, d2=d2, **kw)
            sync(); ts = []
            for _ in range(20):
                t0 = time.perf_counter(); model(*args, target=args[1], d1=d1, d2=d2, **kw)
                sync(); ts.append(1e3 * (time.perf_counter() - t0))
        ts.sort(); med = ts[len(ts) // 2]
        print(f"{label:36s} {W}x{H} grid {P1}x{P0}: median {med:.2f} ms (min {ts[0]:.2f})", flush=True)
        out["runs"].append({"what": label, "size": [W, H], "grid": [P1, P0], "median_ms": med, "min_ms": ts[0]})
os.makedirs(os.environ.get("OUT", "."), exist_ok=True)
json.dump(out, open(os.path.join(os.environ.get("OUT", "."), "gpu_time.json"), "w"), indent=1)
