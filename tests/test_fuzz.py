"""Property-based fuzzing (hypothesis, bounded example counts) of the sidecar parser (TOML and
YAML) and of the result-file loader: any structure, value or byte string gives either a package
error or a valid robot / result."""

from __future__ import annotations

import io
import json
import math
import shutil
import tempfile
from pathlib import Path

import numpy as np
import pytest
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from parallel_gpc import ParallelRobot, load_result, save_result
from parallel_gpc.errors import ParallelGPCError, ResultFormatError
from parallel_gpc.model.description import urdf_dir
from parallel_gpc.results import STANDARD_KEYS

FUZZ = settings(max_examples=60, deadline=None, derandomize=True,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture])
BASE = {
    "name": "fuzzed",
    "output": {"frame": "platform", "joints": ["platform_x", "platform_y", "platform_psi"]},
    "home": {"pose": [0.5, 0.5, 0.0], "branch_joints": ["elbow_1", "elbow_2", "elbow_3"],
             "q_guess": {"drive_1": -0.274, "elbow_1": 2.119, "drive_2": 1.297, "elbow_2": 2.119,
                         "drive_3": -3.416, "elbow_3": 2.119}},
    "drives": {"joints": ["drive_1", "drive_2", "drive_3"], "torque_limit": [60.0, 60.0, 60.0]},
    "closures": [{"name": f"leg_{i}", "kind": "point", "frames": [f"tip_{i}", f"attach_{i}"]} for i in (1, 2, 3)],
}
NAMES = ["drive_1", "drive_2", "elbow_1", "platform_x", "platform_psi", "tip_1", "attach_2", "platform", "", "x"]

scalars = st.one_of(st.booleans(), st.integers(-10**6, 10**6), st.floats(allow_nan=True, allow_infinity=True),
                    st.sampled_from(NAMES), st.text(max_size=8))
values = st.recursive(scalars, lambda inner: st.one_of(st.lists(inner, max_size=4),
                                                        st.dictionaries(st.sampled_from(NAMES + ["kind", "pose"]),
                                                                        inner, max_size=3)), max_leaves=10)
#: Paths into BASE whose value a mutation replaces (or deletes).
PATHS = [("name",), ("output",), ("output", "joints"), ("output", "frame"), ("output", "labels"), ("home",),
         ("home", "pose"), ("home", "q_guess"), ("home", "q_guess", "drive_1"), ("home", "branch_joints"),
         ("drives",), ("drives", "joints"), ("drives", "torque_limit"), ("closures",), ("closures", 0),
         ("closures", 1, "kind"), ("closures", 2, "frames"), ("closures", 0, "name")]


def _mutated(mutations) -> dict:
    data = json.loads(json.dumps(BASE))
    for path, value, delete in mutations:
        node = data
        for key in path[:-1]:
            if isinstance(node, dict) and key in node:
                node = node[key]
            elif isinstance(node, list) and isinstance(key, int) and key < len(node):
                node = node[key]
            else:
                break
        else:
            last = path[-1]
            if isinstance(node, dict):
                if delete:
                    node.pop(last, None)
                else:
                    node[last] = value
            elif isinstance(node, list) and isinstance(last, int) and last < len(node):
                node[last] = value
    return data


def _toml_value(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, float):
        return "nan" if math.isnan(v) else ("inf" if v > 0 else "-inf") if math.isinf(v) else repr(v)
    if isinstance(v, int):
        return str(v)
    if isinstance(v, str):
        return json.dumps(v).replace("\\/", "/")
    if isinstance(v, list):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    return "{" + ", ".join(f"{json.dumps(str(k))} = {_toml_value(x)}" for k, x in v.items()) + "}"


def to_toml(data: dict) -> str:
    """A minimal TOML writer (every table inline): enough for fuzzing the reader."""
    return "".join(f"{json.dumps(str(k))} = {_toml_value(v)}\n" for k, v in data.items())


@pytest.fixture(scope="module")
def folder():
    path = Path(tempfile.mkdtemp(prefix="fuzz-robot-"))
    shutil.copy(urdf_dir() / "planar_3rrr.urdf", path / "r.urdf")
    yield path
    shutil.rmtree(path)


def _load_or_package_error(folder: Path, suffix: str, text: str | bytes) -> None:
    for old in folder.glob("r.*ml"):
        old.unlink()
    path = folder / f"r{suffix}"
    path.write_bytes(text if isinstance(text, bytes) else text.encode("utf-8", "surrogatepass"))
    try:
        robot = ParallelRobot.load(folder / "r.urdf")
    except ParallelGPCError:
        return
    # a valid robot: the closures hold at home and the sizes agree with the description
    assert np.max(np.abs(robot.closure_residual(robot.q_home))) <= 1e-9
    assert robot.n_y == len(robot.description.output_joints) == robot.home_pose.size
    assert robot.n_u == len(set(robot.description.drive_joints))


mutations = st.lists(st.tuples(st.sampled_from(PATHS), values, st.booleans()), min_size=1, max_size=3)


@FUZZ
@given(mutations)
def test_fuzzed_toml_sidecar_gives_a_robot_or_a_package_error(folder, muts):
    _load_or_package_error(folder, ".toml", to_toml(_mutated(muts)))


@FUZZ
@given(mutations)
def test_fuzzed_yaml_sidecar_gives_a_robot_or_a_package_error(folder, muts):
    _load_or_package_error(folder, ".yaml", yaml.safe_dump(_mutated(muts)))


@FUZZ
@given(st.sampled_from([".toml", ".yaml"]), st.one_of(st.binary(max_size=300), st.text(max_size=300)))
def test_random_sidecar_text_gives_a_package_error(folder, suffix, text):
    _load_or_package_error(folder, suffix, text)


def test_the_unmutated_fuzz_base_is_a_valid_robot(folder):
    """The fuzzers start from a valid sidecar (so mutations probe the edge, not only garbage)."""
    for suffix, text in ((".toml", to_toml(BASE)), (".yaml", yaml.safe_dump(BASE))):
        for old in folder.glob("r.*ml"):
            old.unlink()
        (folder / f"r{suffix}").write_text(text)
        assert ParallelRobot.load(folder / "r.urdf").n_u == 3


# ---------------------------------------------------------------------------- result files
dtypes = st.sampled_from(["f8", "f4", "i8", "u1", "?", "U3", "S2", "c16"])
arrays = st.builds(lambda dtype, shape, seed: _array(dtype, shape, seed), dtypes,
                   st.lists(st.integers(0, 4), max_size=3), st.integers(0, 2**16))


def _array(dtype: str, shape: list[int], seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    raw = rng.normal(size=shape) * 10.0 ** rng.integers(-3, 4)
    if rng.random() < 0.2 and raw.size:
        raw.reshape(-1)[0] = rng.choice([np.nan, np.inf])
    if dtype[0] in "US":
        return raw.astype(str).astype(dtype)
    if dtype == "?":
        return raw > 0
    with np.errstate(invalid="ignore", over="ignore"):
        return np.nan_to_num(raw, nan=0, posinf=0, neginf=0).astype(dtype) if dtype[0] in "iu" else raw.astype(dtype)


keys = st.sampled_from(list(STANDARD_KEYS) + ["poses", "u", "extra"])


def _valid_or_package_error(path: Path) -> None:
    try:
        result = load_result(path)
    except ParallelGPCError as exc:
        assert isinstance(exc, ResultFormatError), type(exc)
        return
    assert result.t.ndim == 1 and result.t.size >= 1 and np.all(np.isfinite(result.t))
    assert np.all(np.diff(result.t) > 0)
    if result.q is not None:
        assert result.q.shape[0] == result.t.size and np.all(np.isfinite(result.q))
    for poses in (result.reference, result.planned):
        assert poses is None or (poses.ndim == 2 and poses.shape[1] >= 2 and np.all(np.isfinite(poses)))
    assert isinstance(result.meta, dict) and isinstance(result.robot, str)


@FUZZ
@given(st.dictionaries(keys, arrays, max_size=8), st.booleans())
def test_fuzzed_result_arrays_give_a_result_or_a_package_error(tmp_path, content, versioned):
    if versioned:
        content = {"format": np.array("parallel-gpc-result"), "format_version": np.array(1), **content}
    path = tmp_path / "r.npz"
    np.savez(path, **content)
    _valid_or_package_error(path)


@pytest.fixture(scope="module")
def good_result():
    buf = io.BytesIO()
    t = np.linspace(0.0, 1.0, 6)
    with tempfile.TemporaryDirectory() as tmp:
        path = save_result(Path(tmp) / "g.npz", "planar_4rrr", t, np.zeros((6, 9)), reference=np.ones((6, 3)),
                           meta={"a": 1})
        buf.write(path.read_bytes())
    return buf.getvalue()


@FUZZ
@given(st.data())
def test_corrupted_result_bytes_give_a_result_or_a_package_error(tmp_path, good_result, data):
    raw = bytearray(good_result)
    cut = data.draw(st.integers(0, len(raw)))
    flips = data.draw(st.lists(st.tuples(st.integers(0, len(raw) - 1), st.integers(0, 255)), max_size=6))
    for at, byte in flips:
        raw[at] = byte
    path = tmp_path / "c.npz"
    path.write_bytes(bytes(raw[:cut] if data.draw(st.booleans()) else raw))
    _valid_or_package_error(path)
