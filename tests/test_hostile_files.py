"""Files a command reads that may come from elsewhere (issue 25): zip bombs in rollouts, rollout
files of the wrong shape, dtype, meta or physics, sidecars edited or damaged, a model pair cut
between its two renames, a killed writer's temporaries, a dangling link in the archive. Each is
one `error:` line (or a RolloutError / ModelError from the library), in bounded memory, and
nothing the user had is lost."""

from __future__ import annotations

import io
import json
import os
import re
import resource
import struct
import subprocess
import sys
import tracemalloc
import zipfile
import zlib
from pathlib import Path

import numpy as np
import pytest
from conftest import one_line, run_in_process

from panda_lead import models, rollout, trajectory
from panda_lead.rollout import Rollout, RolloutError

ROOT = Path(__file__).resolve().parents[1]
ENV = {**os.environ, "MUJOCO_GL": "egl"}
T = 50


def run(script, *args, cwd, timeout=None):
    """The script in-process (conftest.run_in_process): its exit status and output, without
    a process (and an `import torch`) per case."""
    return run_in_process(script, *args, cwd=cwd)


def run_process(*args, cwd, timeout=600, **kw):
    """As a process, where the process is the point (its own address-space limit)."""
    return subprocess.run([sys.executable, *map(str, args)], cwd=cwd, capture_output=True,
                          text=True, timeout=timeout, env=ENV, **kw)


def good_rollout(seed: int = 0) -> Rollout:
    t = 0.01 * np.arange(1, T + 1)
    # The seed's own target: a rollout file must hold it to load (rollout.check_against_meta).
    target, vel, acc = trajectory.sample(seed, "circle").at(t)
    z3 = lambda: np.zeros((T, 3))  # noqa: E731  (one array each: a test edits one alone)
    return Rollout(t=t, ee_pos=target + [0.02, 0, 0], target_pos=target.copy(),
                   target_vel=vel.copy(), target_acc=acc.copy(), lead=z3(), qpos=np.zeros((T, 7)),
                   qvel=np.zeros((T, 7)), self_collision=np.zeros(T, bool),
                   collision_depth=np.zeros(T), reachable=np.ones(T, bool),
                   meta={"seed": seed, "shape": "circle", "controller": "classical",
                         "model": None, "dt": 0.01, "duration": T * 0.01})


# --- crafting zips by hand: what zipfile and numpy would never write -------------------------

def deflate(data: bytes) -> bytes:
    c = zlib.compressobj(9, zlib.DEFLATED, -15)
    return c.compress(data) + c.flush()


def zeros_stream(head: bytes, n_zeros: int) -> bytes:
    """A raw deflate stream of ``head`` then ``n_zeros`` zero bytes, built without ever holding
    the zeros: after a full flush the compressor starts afresh, so every MiB of zeros
    compresses to the same ~1 kB piece, which is repeated."""
    mib = 1 << 20
    c = zlib.compressobj(9, zlib.DEFLATED, -15)
    out = [c.compress(head) + c.flush(zlib.Z_FULL_FLUSH)]
    piece = c.compress(bytes(mib)) + c.flush(zlib.Z_FULL_FLUSH)
    out += [piece] * (n_zeros // mib)
    out.append(c.compress(bytes(n_zeros % mib)) + c.flush())
    return b"".join(out)


def write_zip(path: Path, members: list[tuple[str, bytes, int, int]]) -> None:
    """A plain (non-ZIP64) zip of deflated members (name, deflated data, CRC-32, the size it
    declares it expands to), headers written by hand so the declared sizes can lie."""
    out, central = bytearray(), bytearray()
    for name, data, crc, size in members:
        offset, raw = len(out), name.encode()
        out += struct.pack("<IHHHHHIIIHH", 0x04034B50, 20, 0, 8, 0, 0x21, crc, len(data), size,
                           len(raw), 0) + raw + data
        central += struct.pack("<IHHHHHHIIIHHHHHII", 0x02014B50, 20, 20, 0, 8, 0, 0x21, crc,
                               len(data), size, len(raw), 0, 0, 0, 0, 0, offset) + raw
    at = len(out)
    out += central + struct.pack("<IHHHHIIH", 0x06054B50, 0, 0, len(members), len(members),
                                 len(central), at, 0)
    path.write_bytes(bytes(out))


def npy_header(shape: tuple, descr: str = "<f8") -> bytes:
    buf = io.BytesIO()
    np.lib.format.write_array_header_1_0(buf, {"descr": descr, "fortran_order": False,
                                              "shape": shape})
    return buf.getvalue()


def members_of(path: Path, replace: dict[str, tuple[bytes, int, int]]) -> list:
    """A real rollout file's members, deflated anew, with some replaced by (data, crc, size)."""
    out = []
    with zipfile.ZipFile(path) as z:
        for info in z.infolist():
            name = info.filename.removesuffix(".npy")
            if name in replace:
                out.append((info.filename, *replace[name]))
            else:
                raw = z.read(info)
                out.append((info.filename, deflate(raw), zlib.crc32(raw), len(raw)))
    return out


FOUR_GB = 0xF000_0000  # what the bomb member declares: 4.0 GB, within a plain zip's 32 bits


@pytest.fixture
def bomb(tmp_path) -> Path:
    """A rollout whose ee_pos member really expands to 4 GB of zeros (a valid .npy of
    167 million rows) from a 4 MB file; built in ~4 MB of memory."""
    good = rollout.save(good_rollout(), tmp_path / "good.npz")
    head = npy_header(((FOUR_GB - 128) // 24, 3))
    assert len(head) == 128
    size = len(head) + 24 * ((FOUR_GB - 128) // 24)
    stream = zeros_stream(head, size - len(head))
    # The CRC is left 0: computing it means reading 4 GB, and no reader may get that far.
    path = tmp_path / "rollouts" / "bomb" / "seed_0000.npz"
    path.parent.mkdir(parents=True)
    write_zip(path, members_of(good, {"ee_pos": (stream, 0, size)}))
    assert path.stat().st_size < 8 * 2**20
    return path


# --- item 1: a rollout member that expands to gigabytes ---------------------------------------

def test_a_rollout_member_that_expands_to_gigabytes_is_refused_in_bounded_memory(bomb):
    tracemalloc.start()
    try:
        with pytest.raises(RolloutError, match=r"ee_pos would expand to 4,026,531,8\d\d bytes"):
            rollout.load(bomb)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 64 * 2**20, f"{peak / 2**20:.0f} MiB"
    assert rollout.read_meta(bomb)["seed"] == 0  # the meta alone is still readable


def test_metrics_on_a_zip_bomb_is_one_line_within_a_2_gib_address_space(bomb):
    """metrics.py peaked at 9.4 GB on such a file. Under a 2 GiB address-space limit (a real
    metrics run fits in it), it must answer with one line, not a MemoryError."""
    good = bomb.parent.parent / "good"
    good.mkdir()
    rollout.save(good_rollout(), good / "seed_0000.npz")

    def limit():
        resource.setrlimit(resource.RLIMIT_AS, (2 * 2**30, 2 * 2**30))

    out = run_process(ROOT / "metrics.py", "--root", bomb.parent.parent, "--prefix-a", "good",
                      "--prefix-b", "bomb", "--bootstrap", "200", cwd=bomb.parent,
                      preexec_fn=limit)
    one_line(out, str(bomb), "ee_pos would expand to")


def test_a_member_that_lies_about_its_size_is_refused_before_allocating(tmp_path):
    """Two lies a bound on the declared size does not catch: a member declaring 1 MiB whose
    stream goes on to 4 GB (read only up to what it declares), and a .npy header declaring
    10^12 rows over a few bytes (numpy would allocate the array before reading it)."""
    good = rollout.save(good_rollout(), tmp_path / "good.npz")
    head = npy_header(((FOUR_GB - 128) // 24, 3))
    mib = 1 << 20
    stream = zeros_stream(head, FOUR_GB - 128)
    first = head + bytes(mib - len(head))
    liar = tmp_path / "liar.npz"
    write_zip(liar, members_of(good, {"ee_pos": (stream, zlib.crc32(first), mib)}))
    with pytest.raises(RolloutError, match=r"ee_pos's header says \(167772154, 3\) float64, "
                       r"but it holds 1,048,448 bytes"):
        rollout.load(liar)
    raw = npy_header((10**12, 3)) + bytes(48)
    huge = tmp_path / "huge_header.npz"
    write_zip(huge, members_of(good, {"qpos": (deflate(raw), zlib.crc32(raw), len(raw))}))
    with pytest.raises(RolloutError, match=r"qpos's header says \(1000000000000, 3\)"):
        rollout.load(huge)


def test_a_meta_member_bomb_is_refused_by_read_meta(tmp_path):
    """read_meta (what the rollout writer reads to check a folder) is bounded too."""
    good = rollout.save(good_rollout(), tmp_path / "good.npz")
    head = npy_header((), "<U1000000000")
    size = len(head) + 4 * 10**9 // 1000 * 1000
    bomb = tmp_path / "meta_bomb.npz"
    write_zip(bomb, members_of(good, {"meta": (zeros_stream(head, size - len(head)), 0,
                                              min(size, 0xFFFF_FFFE))}))
    with pytest.raises(RolloutError, match="meta would expand to"):
        rollout.read_meta(bomb)


# --- items 17 and 10: shapes, dtypes, meta, physics ---------------------------------------------

def _edit(r: Rollout, case: str) -> Rollout:
    if case == "wrong_columns":
        r.ee_pos = r.ee_pos[:, :2]
    elif case == "ragged_T":
        r.qpos = r.qpos[:-1]
    elif case == "empty":
        for k in rollout.ARRAY_KEYS:
            setattr(r, k, getattr(r, k)[:0])
    elif case == "string_dtype":
        r.target_vel = r.target_vel.astype(str)
    elif case == "complex_dtype":
        r.lead = r.lead.astype(complex)
    elif case == "float_flags":
        r.reachable = r.reachable.astype(float)
    elif case == "meta_not_object":
        r.meta = [1, 2, 3]  # type: ignore[assignment]
    elif case == "meta_seed_string":
        r.meta["seed"] = "seven"
    elif case == "meta_negative_dt":
        r.meta["dt"] = -0.01
    elif case == "meta_nan_duration":
        r.meta["duration"] = float("nan")
    elif case == "meta_no_shape":
        del r.meta["shape"]
    return r


DAMAGED = {
    "wrong_columns": "ee_pos has shape (50, 2), expected (T, 3)",
    "ragged_T": "qpos has shape (49, 7), expected (T, 7) with the same T >= 1 as t (50,)",
    "empty": "t has shape (0,), expected (T,) with the same T >= 1",
    "string_dtype": "target_vel has dtype <U32, expected numbers",
    "complex_dtype": "lead has dtype complex128",
    "float_flags": "reachable has dtype float64, expected bool",
    "meta_not_object": "meta must be a JSON object, got list",
    "meta_seed_string": "meta seed must be an integer",
    "meta_negative_dt": "meta dt must be a positive finite number, got -0.01",
    "meta_nan_duration": "meta duration must be a positive finite number, got nan",
    "meta_no_shape": "meta shape must be a name, got None",
}


@pytest.mark.parametrize("case", list(DAMAGED))
def test_a_rollout_of_the_wrong_shape_dtype_or_meta_is_one_clear_error(tmp_path, case):
    path = rollout.save(_edit(good_rollout(), case), tmp_path / "seed_0000.npz")
    with pytest.raises(RolloutError) as exc:
        rollout.load(path)
    assert str(exc.value).startswith(f"{path}: not a valid rollout file (")
    assert DAMAGED[case] in str(exc.value)


def test_meta_that_is_not_json_is_one_clear_error(tmp_path):
    path = tmp_path / "seed_0000.npz"
    good = rollout.save(good_rollout(), tmp_path / "good.npz")
    arrays = dict(np.load(good))
    arrays["meta"] = np.array("{not json")
    np.savez_compressed(path, **arrays)
    with pytest.raises(RolloutError, match="meta is not JSON"):
        rollout.load(path)


@pytest.mark.parametrize("key,step,value,words", [
    ("ee_pos", 7, 1e300, "beyond 100 m, farther than any position"),
    ("target_pos", 0, -2e3, "beyond 100 m"),
    ("qvel", 49, 3e5, "beyond 10000 rad/s"),
    ("target_vel", 3, 1e5, "beyond 10000 m/s"),
])
def test_a_finite_value_beyond_physics_is_a_damaged_file(tmp_path, key, step, value, words):
    """1e300 in ee_pos used to overflow the error to inf and drop the seed from one set
    silently. Any position beyond 100 m or speed beyond 1e4 is refused, naming the file, the
    array and the step; NaN and inf still load (metrics names those seeds and leaves them
    out of every set)."""
    r = good_rollout()
    getattr(r, key)[step, 1] = value
    path = rollout.save(r, tmp_path / "seed_0000.npz")
    with pytest.raises(RolloutError, match=re.escape(f"{key} holds {value:g} at step {step}, "
                                                     f"{words}")):
        rollout.load(path)
    getattr(r, key)[step, 1] = np.nan
    rollout.save(r, path)
    assert np.isnan(getattr(rollout.load(path), key)[step, 1])


def test_damaged_rollouts_are_one_line_through_metrics_py(tmp_path):
    for prefix in ("a", "b"):
        for s in range(3):
            rollout.save(good_rollout(s), rollout.rollout_path(prefix, s, tmp_path))
    r = good_rollout(1)
    r.ee_pos[7, 1] = 1e300
    bad = rollout.save(r, rollout.rollout_path("b", 1, tmp_path))
    out = run(ROOT / "metrics.py", "--root", tmp_path, "--prefix-a", "a", "--prefix-b", "b",
              "--bootstrap", "200", cwd=tmp_path)
    one_line(out, str(bad), "ee_pos holds 1e+300 at step 7")
    r = good_rollout(1)
    r.qpos = r.qpos[:, :6]
    rollout.save(r, bad)
    out = run(ROOT / "metrics.py", "--root", tmp_path, "--prefix-a", "a", "--prefix-b", "b",
              "--bootstrap", "200", cwd=tmp_path)
    one_line(out, str(bad), "qpos has shape (50, 6)")


# --- models: items 2, 6, 16, 20 ----------------------------------------------------------------

@pytest.fixture(scope="module")
def model(tmp_path_factory):
    """A real (untrained) PPO model with its sidecar, saved the way train.py saves models."""
    from stable_baselines3 import PPO

    from panda_lead.env import PandaLeadEnv
    from panda_lead.models import save_model

    tmp = tmp_path_factory.mktemp("model")
    e = PandaLeadEnv()
    m = PPO("MlpPolicy", e, n_steps=64, batch_size=64, device="cpu",
            policy_kwargs={"net_arch": [16, 16]})
    return save_model(m, tmp / "m.zip", {"env_config": e.config, "train_config": {},
                                         "timesteps": 0})


def copy_pair(src: Path, dst: Path) -> Path:
    dst.write_bytes(src.read_bytes())
    dst.with_suffix(".json").write_text(src.with_suffix(".json").read_text())
    return dst


def edit_json(path: Path, edit) -> None:
    side = json.loads(path.with_suffix(".json").read_text())
    edit(side)
    path.with_suffix(".json").write_text(json.dumps(side))


def test_an_edited_sidecar_is_refused_and_only_what_the_zip_carries_decides(model, tmp_path):
    """tanh -> relu in a copy's JSON: refused in one line (the zip carries its sidecar, and
    the JSON must equal it). Bound on purpose (`bind_sidecar`, a trusted re-bind), relu is
    what the zip carries, so relu is what loads."""
    import torch

    from panda_lead.models import bind_sidecar, load_policy

    copy = copy_pair(model, tmp_path / "relu.zip")
    edit_json(copy, lambda s: s["policy"].update(activation_fn="relu"))
    before = sorted(p.name for p in tmp_path.iterdir())
    out = run(ROOT / "eval.py", "--seeds", "0", "--prefix", "x", "--model", copy,
              "--duration", "0.1", cwd=tmp_path)
    one_line(out, "differs from the sidecar the model carries (policy", "--restore-sidecar")
    assert sorted(p.name for p in tmp_path.iterdir()) == before

    acts = lambda p: {type(m) for m in p.mlp_extractor.policy_net}  # noqa: E731
    assert torch.nn.Tanh in acts(load_policy(model)[0])
    bind_sidecar(copy)
    policy, _, side = load_policy(copy)
    assert torch.nn.ReLU in acts(policy) and torch.nn.Tanh not in acts(policy)
    assert side["model_sha256"] != json.loads(model.with_suffix(".json").read_text())[
        "model_sha256"]  # the rollouts it writes record another model


@pytest.mark.parametrize("edit,words", [
    (lambda s: s["policy"].update(net_arch=[200000, 200000]), "net_arch must be 1-8 layer widths"),
    (lambda s: s["policy"].update(net_arch={"pi": [64], "vf": [64], "x": [1]}), "net_arch"),
    (lambda s: s["policy"].update(activation_fn=3), "unknown activation 3"),
    (lambda s: s["policy"].update(log_std_init="nan"), "log_std_init must be a finite number"),
    (lambda s: s.update(timesteps="x"), "timesteps must be an integer >= 0, got 'x'"),
    (lambda s: s["env_config"].update(obs_features=5), "bad.json: "),
    (lambda s: s["env_config"].update(max_lead="x"), "max_lead must be a finite number"),
    (lambda s: s.update(rates={"physics_hz": 1000, "control_hz": 100}), "another plant"),
])
def test_damaged_sidecar_types_and_absurd_architectures_are_refused(model, tmp_path, edit,
                                                                    words):
    """Each flaw is bound into the zip too (so the pair is consistent and the schema check is
    what must refuse it), and refused before torch builds anything: a 200,000-wide layer
    would be 160 GB."""
    from panda_lead.models import ModelError, bind_sidecar, load_policy

    copy = copy_pair(model, tmp_path / "bad.zip")
    edit_json(copy, edit)
    bind_sidecar(copy)
    tracemalloc.start()
    try:
        with pytest.raises(ModelError, match=re.escape(words)):
            load_policy(copy)
        assert tracemalloc.get_traced_memory()[1] < 256 * 2**20
    finally:
        tracemalloc.stop()


def test_a_sidecar_whose_feature_list_is_a_number_names_the_field(model, tmp_path):
    from panda_lead.models import ModelError, bind_sidecar, load_policy

    copy = copy_pair(model, tmp_path / "bad.zip")
    edit_json(copy, lambda s: s["env_config"].update(obs_features=5))
    bind_sidecar(copy)
    with pytest.raises(ModelError, match="obs_features"):  # today: "'int' object is not iterable"
        load_policy(copy)


def test_a_damaged_sidecar_is_one_line_through_eval_py(model, tmp_path):
    from panda_lead.models import bind_sidecar

    copy = copy_pair(model, tmp_path / "bad.zip")
    edit_json(copy, lambda s: s["policy"].update(net_arch=[200000, 200000]))
    bind_sidecar(copy)
    out = run(ROOT / "eval.py", "--seeds", "0", "--prefix", "x", "--model", copy,
              "--duration", "0.1", cwd=tmp_path)
    one_line(out, "net_arch must be 1-8 layer widths")
    assert not (tmp_path / "rollouts").exists()


def test_a_pair_cut_between_its_two_renames_stays_loadable_or_restorable(model, tmp_path,
                                                                        monkeypatch):
    """write_pair renames the JSON into place, then the zip. A kill after the JSON's rename
    leaves the old zip beside the new JSON: refused in one line that says how to restore, and
    `eval.py --model X --restore-sidecar` brings back the old, loadable pair. A kill before
    the JSON's rename leaves the old pair as it was."""
    from stable_baselines3 import PPO

    from panda_lead import atomicio
    from panda_lead.env import PandaLeadEnv
    from panda_lead.models import ModelError, load_policy, save_model

    target = copy_pair(model, tmp_path / "m.zip")
    old_zip, old_json = target.read_bytes(), target.with_suffix(".json").read_text()
    e = PandaLeadEnv()
    new = PPO("MlpPolicy", e, n_steps=64, batch_size=64, device="cpu", seed=1,
              policy_kwargs={"net_arch": [16, 16]})
    plain_replace = atomicio.os.replace

    def killed_at(suffix):
        def replace(src, dst):
            if str(dst).endswith(suffix):
                raise KeyboardInterrupt  # the kill lands here
            return plain_replace(src, dst)
        return replace

    sidecar = {"env_config": e.config, "train_config": {}, "timesteps": 64}
    monkeypatch.setattr(atomicio.os, "replace", killed_at(".json"))
    with pytest.raises(KeyboardInterrupt):
        save_model(new, target, sidecar)
    assert (target.read_bytes(), target.with_suffix(".json").read_text()) == (old_zip, old_json)
    load_policy(target)

    monkeypatch.setattr(atomicio.os, "replace", killed_at(".zip"))
    with pytest.raises(KeyboardInterrupt):
        save_model(new, target, sidecar)
    monkeypatch.setattr(atomicio.os, "replace", plain_replace)
    assert target.read_bytes() == old_zip  # the zip is whole: the old one
    assert target.with_suffix(".json").read_text() != old_json  # the new JSON landed
    with pytest.raises(ModelError, match="--restore-sidecar"):
        load_policy(target)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["m.json", "m.zip"]  # no temporaries
    out = run(ROOT / "eval.py", "--model", target, "--restore-sidecar", cwd=tmp_path)
    assert out.returncode == 0, out.stderr
    assert json.loads(target.with_suffix(".json").read_text()) == json.loads(old_json)
    load_policy(target)


def test_a_full_disk_while_writing_the_json_keeps_the_previous_pair(model, tmp_path,
                                                                   monkeypatch):
    """(The zip's own full disk: test_reliability.py::test_a_full_disk_is_one_line_and_keeps_
    the_previous_files.) Here the zip is written, then the JSON hits a full disk."""
    import errno

    from stable_baselines3 import PPO

    from panda_lead import models
    from panda_lead.env import PandaLeadEnv
    from panda_lead.errors import UserError

    target = copy_pair(model, tmp_path / "m.zip")
    before = target.read_bytes(), target.with_suffix(".json").read_text()
    e = PandaLeadEnv()
    new = PPO("MlpPolicy", e, n_steps=64, batch_size=64, device="cpu",
              policy_kwargs={"net_arch": [16, 16]})

    def full(*a, **k):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(models.json, "dump", full)
    with pytest.raises(UserError, match="cannot write .*m.json: No space left on device"):
        models.save_model(new, target, {"env_config": e.config, "train_config": {},
                                        "timesteps": 64})
    assert (target.read_bytes(), target.with_suffix(".json").read_text()) == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["m.json", "m.zip"]
    models.load_policy(target)


def test_a_dangling_link_in_the_archive_does_not_break_eval(tmp_path):
    """eval.py without --model runs the named default model (models.DEFAULT_MODEL), found in
    ./archive or the archive shipped with the package; a dangling link there, even under that
    very name, is neither the newest file nor a crash."""
    name = f"{models.DEFAULT_MODEL}.zip"
    archive = tmp_path / "archive"
    archive.mkdir()
    (archive / "zzz_newest.zip").symlink_to(tmp_path / "gone.zip")
    (archive / name).symlink_to(tmp_path / "gone_too.zip")
    out = run(ROOT / "eval.py", "--seeds", "0", "--prefix", "p", "--duration", "0.1",
              cwd=tmp_path)
    assert out.returncode == 0, out.stderr
    meta = rollout.read_meta(tmp_path / "rollouts" / "p" / "seed_0000.npz")
    assert meta["model"].endswith(f"archive/{name}") and meta["model_sha256"]
    assert Path(meta["model"]).resolve() != (archive / name).absolute()


# --- a killed writer's temporaries ------------------------------------------------------------

KILLED_WRITER = """
import sys, time
from panda_lead.atomicio import atomic_write
with atomic_write(sys.argv[1], ".tmp.npz") as tmp:
    open(tmp, "wb").write(b"half a file")
    print(tmp, flush=True)
    time.sleep(600)  # killed here
"""


def test_a_killed_writers_temporary_is_removed_by_the_next_write(tmp_path):
    """SIGKILL leaves the hidden temporary (no handler runs). The next write of the same
    target removes it once it is older than any write takes (atomicio.STALE_TEMP_S), and
    leaves a fresh one alone (another writer's, still working)."""
    import signal

    from panda_lead.atomicio import STALE_TEMP_S

    target = tmp_path / "seed_0000.npz"
    proc = subprocess.Popen([sys.executable, "-c", KILLED_WRITER, str(target)],
                            stdout=subprocess.PIPE, text=True, env=ENV)
    try:
        stale = Path(proc.stdout.readline().strip())  # the event: the temporary exists
        proc.send_signal(signal.SIGKILL)
        proc.wait(timeout=600)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert stale.is_file() and stale.name.startswith(".seed_0000.") and not target.exists()
    old = stale.stat().st_mtime - STALE_TEMP_S - 60
    os.utime(stale, (old, old))  # as if killed 11 minutes ago
    fresh = tmp_path / ".seed_0000.fresh.tmp.npz"
    fresh.write_bytes(b"another writer, now")
    rollout.save(good_rollout(), target)
    assert not stale.exists() and fresh.exists()
    assert rollout.load(target).seed == 0


def test_a_model_member_that_expands_beyond_its_bound_is_refused_before_reading(model, tmp_path):
    """Item 1 (models): a 3 MB zip whose policy.pth (or embedded sidecar) expanded to 3 GiB made
    eval.py peak at 6.9 GB. A member larger than its bound is refused from its header, and a
    read never goes past the bound whatever the header says."""
    import zipfile

    from panda_lead.models import (
        MAX_JSON_BYTES,
        MAX_TENSOR_MEMBER_BYTES,
        ModelError,
        bind_sidecar,
        file_sha256,
        load_policy,
        read_member,
    )

    bomb = tmp_path / "bomb.zip"
    with zipfile.ZipFile(model) as zin, zipfile.ZipFile(bomb, "w", zipfile.ZIP_DEFLATED) as zout:
        for info in zin.infolist():
            if info.filename != "policy.pth":
                zout.writestr(info, zin.read(info))
        with zout.open("policy.pth", "w", force_zip64=True) as f:  # really 300 MiB of zeros
            chunk = bytes(2**20)
            for _ in range(MAX_TENSOR_MEMBER_BYTES // 2**20 + 44):
                f.write(chunk)
    # A hostile pair is self-consistent (the hash is not a signature): its JSON names its hash.
    edit_json(copy_pair(model, tmp_path / "m.zip"), lambda s: s.update(
        model_sha256=file_sha256(bomb)))
    bomb.with_suffix(".json").write_text((tmp_path / "m.json").read_text())
    assert bomb.stat().st_size < 2 * 2**20
    with pytest.raises(ModelError, match="policy.pth would expand"):
        bind_sidecar(bomb)  # even the trusted re-bind copies members within their bounds
    with pytest.raises(ModelError, match="policy.pth would expand to 3"):
        load_policy(bomb)
    with pytest.raises(ModelError, match="more than the 1,048,576 allowed"):
        read_member(bomb, "policy.pth", MAX_JSON_BYTES)
