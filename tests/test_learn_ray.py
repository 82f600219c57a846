"""The data set builder on Ray (issue 5): ``build_dataset(..., ray_address=...)``, ``vrcorrect dataset --ray``.

Ray 2.60 no longer has ``local_mode``, so the module starts one one-node Ray (2 CPUs, no
dashboard) and shuts it down at the end; the builder uses a connection it finds open.  The
data set is the tiny one of test_learn.py (3 samples of 32x32, 2 shards).  Ray is the extra
``ray``, which tools/setup.sh installs: these tests run, never skip.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from vrcorrect.plumbing.errors import InputError
from vrcorrect.learn.dataset import MANIFEST, build_dataset, load_shard, read_manifest

from test_learn import tiny_config, tiny_images


@pytest.fixture(scope="module")
def ray_cluster():
    import ray

    ray.init(address="local", num_cpus=2, include_dashboard=False, object_store_memory=100 * 1024 ** 2)
    yield ray
    ray.shutdown()


@pytest.fixture(scope="module")
def builds(ray_cluster, tmp_path_factory) -> tuple[Path, Path]:
    root = tmp_path_factory.mktemp("ray")
    build_dataset(root / "local", tiny_images(), tiny_config(), workers=1, progress=False)
    report = build_dataset(root / "ray", tiny_images(), tiny_config(), ray_address="local", progress=False)
    assert (report.computed_shards, report.skipped_shards) == (2, 0)
    assert ray_cluster.is_initialized()              # the caller's Ray is left running
    return root / "local", root / "ray"


def _entries(out: Path) -> list[dict]:
    """The manifest's shard entries without the timings."""
    entries = read_manifest(out)["shards"]
    return [{**e, "samples": [{k: v for k, v in s.items() if k != "seconds"} for s in e["samples"]]}
            for e in entries]


def assert_same_dataset(a: Path, b: Path) -> None:
    ma, mb = read_manifest(a), read_manifest(b)
    for key in ("config", "display", "images", "reference", "solver"):
        assert ma[key] == mb[key], key
    assert _entries(a) == _entries(b)
    for ea, eb in zip(ma["shards"], mb["shards"]):
        sa, sb = load_shard(a, ea), load_shard(b, eb)
        assert sa.keys() == sb.keys()
        for key in sa:
            np.testing.assert_array_equal(sa[key], sb[key], err_msg=f"shard {ea['shard']} {key}")
            assert sa[key].dtype == sb[key].dtype


def test_ray_build_equals_local_build(builds):
    """Same arrays (bit for bit), same manifest apart from the timings."""
    local, ray_out = builds
    assert_same_dataset(local, ray_out)


def test_ray_build_resumes_locally_and_the_other_way(builds, tmp_path):
    import shutil

    local, ray_out = builds
    out = tmp_path / "d"
    shutil.copytree(ray_out, out)
    # a Ray build interrupted before shard 1 was recorded: the local builder finishes it
    (out / "shard_00001.npz").unlink()
    m = json.loads((out / MANIFEST).read_text())
    m["shards"] = [e for e in m["shards"] if e["shard"] != 1]
    (out / MANIFEST).write_text(json.dumps(m))
    built: list[int] = []
    report = build_dataset(out, tiny_images(), tiny_config(), workers=1, progress=False, on_shard=built.append)
    assert built == [1] and (report.computed_shards, report.skipped_shards) == (1, 1)
    # a local build whose shard 0 is lost: Ray computes only that one
    (out / "shard_00000.npz").unlink()
    built.clear()
    report = build_dataset(out, tiny_images(), tiny_config(), ray_address="local", progress=False,
                           on_shard=built.append)
    assert built == [0] and (report.computed_shards, report.skipped_shards) == (1, 1)
    assert_same_dataset(local, out)
    # nothing left to do: Ray is not even needed
    assert build_dataset(out, tiny_images(), tiny_config(), ray_address="local", progress=False).computed_shards == 0


def test_user_error_inside_a_ray_task_is_reported_as_itself(ray_cluster, tmp_path, monkeypatch):
    """A vrcorrect error raised in a task reaches the caller as that error (one line), not Ray's wrapper."""
    from vrcorrect.learn import dataset

    def bad_shard(source, data, config, shard, specs):
        raise InputError(f"shard {shard}: broken on purpose")

    monkeypatch.setattr(dataset, "_ray_shard", bad_shard)
    with pytest.raises(InputError, match=r"^shard \d: broken on purpose$"):
        build_dataset(tmp_path / "d", tiny_images(), tiny_config(), ray_address="local", progress=False)


# --------------------------------------------------------------------------
# Ray missing, Ray unreachable (no Ray needed in this process)
# --------------------------------------------------------------------------

def test_missing_ray_names_the_extra(tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "ray", None)             # import ray -> ImportError
    with pytest.raises(InputError, match=r"--ray auto: Ray is not installed.*pip install -e '\.\[ray\]'"):
        build_dataset(tmp_path / "d", tiny_images(), tiny_config(), ray_address="auto", progress=False)
    assert not (tmp_path / "d").exists()


def _cli(code: str, env: dict | None = None) -> tuple[int, list[str]]:
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120,
                       env={**{k: v for k, v in os.environ.items() if k != "RAY_ADDRESS"}, **(env or {})})
    return r.returncode, r.stderr.strip().splitlines()


def test_cli_missing_ray_is_one_line(tmp_path):
    code, err = _cli("import sys; sys.modules['ray'] = None; from vrcorrect.apps.cli import main; "
                     f"sys.exit(main(['dataset', {str(tmp_path / 'd')!r}, '--ray', 'auto']))")
    assert code == 2 and len(err) == 1, err
    assert "Ray is not installed" in err[0] and "pip install -e '.[ray]'" in err[0]


def test_cli_unreachable_address_is_one_line(tmp_path):
    """Nothing listens on port 1: one line naming the address, exit 2, no folder left behind."""
    out = tmp_path / "d"
    code, err = _cli("import sys; from vrcorrect.apps.cli import main; "
                     f"sys.exit(main(['dataset', {str(out)!r}, '--ray', 'ray://127.0.0.1:1', '--samples', '1', "
                     "'--crop-px', '32', '--image-px', '48']))",
                     env={"RAY_CLIENT_INITIAL_CONNECTION_TIMEOUT_S": "1", "RAY_CLIENT_MAX_CONNECTION_TIMEOUT_S": "1"})
    assert code == 2 and len(err) == 1, err
    assert err[0].startswith("vrcorrect: error: --ray ray://127.0.0.1:1: cannot connect to Ray")
    assert not out.exists()


def test_ray_is_imported_lazily():
    code, err = _cli("import sys, vrcorrect.learn.dataset, vrcorrect.apps.learning, vrcorrect.apps.cli; "
                     "sys.exit(1 if 'ray' in sys.modules else 0)")
    assert code == 0, err


def test_the_unrolled_models_kernels_on_ray_equal_local_ones(ray_cluster):
    """vrcorrect unroll --ray: build_pool's eyes as Ray tasks give the same eyes, in the same order,
    with the same kernels (bit for bit) as local processes."""
    from vrcorrect.learn.unrolled_train import UnrolledTrainConfig, build_pool

    config = UnrolledTrainConfig(displays=("index",), eyes_per_display=2, held_out_eyes_per_display=1)
    local = build_pool(config, workers=1)
    on_ray = build_pool(config, ray_address="local")
    assert ray_cluster.is_initialized()                  # the caller's Ray is left running
    for split in ("train", "held_out"):
        assert len(on_ray[split]) == len(local[split]) > 0
        for a, b in zip(local[split], on_ray[split]):
            assert a.eye == b.eye and a.display == b.display
            np.testing.assert_array_equal(a.kernel, b.kernel)
            np.testing.assert_array_equal(a.reference, b.reference)
            np.testing.assert_array_equal(a.features, b.features)
