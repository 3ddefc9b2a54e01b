"""Generated inputs thrown at the public API and the converters' readers (Hypothesis, derandomized).

Every input either works (finite answers of the documented shapes) or raises a ValueError/TypeError whose
message names an argument (or, for a demo file, the file) that is wrong. An oracle says which inputs are
valid, so the test also fails when a good input is refused. Each test prints its case count and time.
"""

from __future__ import annotations

import numbers
import time
import warnings
from collections import Counter
from pathlib import Path

import numpy as np
import pytest
import torch
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from datasets_conv import dedo, nist, rpdiff
from datasets_conv.pipeline import ConversionOptions, DemoRef
from datasets_conv.samples import (
    dedo_goal_demo,
    nist_demo,
    rpdiff_demo,
    save_dedo_goal_demo,
    save_nist_npz,
    save_rpdiff_demo,
)
from lerobot_taxdpd import load_goal_predictor
from lerobot_taxdpd.data.validation import MAX_COORDINATE
from test_policy import clouds, tiny_policy

FLOAT_DTYPES = ("float32", "float64", "float16", "bfloat16", ">f4")
DTYPES = (*FLOAT_DTYPES, "int64", "bool", "complex64", "object")
SCALES = (0.0, 1e-30, 1e-6, 1.0, 1e3, MAX_COORDINATE, 1e7, 1e20, 1e300)
LAYOUTS = ("contiguous", "transposed", "strided", "reversed", "expanded", "meta", "sparse")
NON_FINITE = (None, float("nan"), float("inf"), float("-inf"))


def _settings(examples: int):
    """Reproducible in CI (derandomized, no example database), no per-call deadline: time is printed instead."""
    return settings(
        max_examples=examples,
        deadline=None,
        derandomize=True,
        database=None,
        suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture],
    )


def _report(what: str, outcomes: Counter, start: float) -> None:
    print(f"\n{what}: {sum(outcomes.values())} generated cases in {time.perf_counter() - start:.1f} s {dict(outcomes)}")


# ------------------------------------------------------------------------------------------- arrays
@st.composite
def arrays(draw, points: tuple[int, ...] = (0, 1, 2, 3, 17, 40, 90), layouts: tuple[str, ...] = LAYOUTS):
    """A cloud-like array of any container, shape, dtype, scale, layout, with NaN or inf sometimes."""
    shape = [draw(st.sampled_from((1, 1, 2, 0))), draw(st.sampled_from(points)), draw(st.sampled_from((3, 3, 3, 2, 4)))]
    rank = draw(st.sampled_from(("batched", "batched", "unbatched", "extra")))
    shape = shape[1:] if rank == "unbatched" else [1, *shape] if rank == "extra" else shape
    rng = np.random.default_rng(draw(st.integers(0, 2**16)))
    values = rng.normal(size=shape) * draw(st.sampled_from(SCALES)) + draw(st.sampled_from((0.0, 0.0, 5.0, -1e5)))
    bad = draw(st.sampled_from(NON_FINITE))
    if bad is not None and values.size:
        values.flat[rng.integers(values.size)] = bad
    return _laid_out(
        _typed(values, draw(st.sampled_from(DTYPES)), draw(st.sampled_from(("tensor", "numpy")))),
        draw(st.sampled_from(layouts)),
    )


def _typed(values: np.ndarray, dtype: str, container: str):
    """`values` as a numpy array or a tensor of `dtype` (numpy-only dtypes fall back to float32 for tensors)."""
    with np.errstate(over="ignore", invalid="ignore"):
        if container == "numpy":
            return values.astype("float32" if dtype == "bfloat16" else dtype)
        if dtype == "bfloat16":
            return torch.from_numpy(values).to(torch.bfloat16)
        return torch.from_numpy(values.astype("float32" if dtype in (">f4", "object") else dtype))


def _laid_out(array, layout: str):
    """The same values as a non-contiguous view (transposed storage, every other row, reversed rows, broadcast),
    or as a tensor without plain values (on the meta device, sparse)."""
    if array.ndim < 2 or layout == "contiguous":
        return array
    if layout == "transposed":
        if isinstance(array, np.ndarray):
            return np.ascontiguousarray(np.swapaxes(array, -1, -2)).swapaxes(-1, -2)
        return array.transpose(-1, -2).contiguous().transpose(-1, -2)
    if layout == "strided":
        doubled = np.repeat(array, 2, axis=-2) if isinstance(array, np.ndarray) else array.repeat_interleave(2, -2)
        return doubled[..., ::2, :]
    if layout == "reversed":
        return array[..., ::-1, :] if isinstance(array, np.ndarray) else array.flip(-2)
    if isinstance(array, np.ndarray):
        return array
    if layout == "expanded":
        return array[..., :1, :].expand(array.shape)
    return array.to("meta") if layout == "meta" else array.to_sparse()


def is_valid_cloud(array, min_points: int = 3) -> bool:
    """The documented contract: a float (B >= 1, N >= min_points, 3) array, finite and within MAX_COORDINATE."""
    if isinstance(array, torch.Tensor) and (array.layout != torch.strided or array.is_meta):
        return False
    if not isinstance(array, (np.ndarray, torch.Tensor)) or str(array.dtype).split(".")[-1] not in (
        *FLOAT_DTYPES,
        "float32",
    ):
        return False
    if array.ndim != 3 or array.shape[0] < 1 or array.shape[1] < min_points or array.shape[2] != 3:
        return False
    values = array.float().numpy() if isinstance(array, torch.Tensor) else array.astype(np.float64)
    return bool(np.isfinite(values).all() and np.abs(values).max() <= MAX_COORDINATE)


# ----------------------------------------------------------------------------------------- policy API
OPTIONS = {
    "num_samples": (1, 2, 3, np.int64(2), 0, -1, 2.0, "2", None),
    "num_inference_steps": (None, 1, 2, 4, 3, 0, 2.0),
    "sampler": (None, "ddim", "ddpm", "DDIM", "", ["ddim"]),
    "generator": (None, torch.Generator().manual_seed(0), "seed", 3),
}


def _option_is_valid(name: str, value) -> bool:
    if name == "num_samples":
        return isinstance(value, numbers.Integral) and value >= 1
    if name == "num_inference_steps":
        return value is None or (isinstance(value, int) and value >= 1 and 100 % value == 0)
    if name == "generator":
        return isinstance(value, torch.Generator)
    return value in (None, "ddim", "ddpm")


def _mostly(draw, good, fuzzed: st.SearchStrategy):
    """`good` three times in four, so most calls get past the checks and run the network."""
    return good if draw(st.integers(0, 3)) else draw(fuzzed)


@st.composite
def api_calls(draw):
    """(method, object_points, scene_points, options), each argument fuzzed a quarter of the time."""
    method = draw(st.sampled_from(("sample_goals", "predict_poses", "placement_distribution")))
    good_object, good_scene = clouds(1, seed=draw(st.integers(0, 99)))
    object_points = _mostly(draw, good_object, st.one_of(arrays(), st.sampled_from((None, [[0.0, 0.0, 0.0]]))))
    scene_points = _mostly(draw, good_scene, st.one_of(arrays(), st.just(good_scene.numpy())))
    options = {}
    if method != "placement_distribution":
        options = {name: _mostly(draw, values[0], st.sampled_from(values)) for name, values in OPTIONS.items()}
        options = {name: value for name, value in options.items() if name == "num_samples" or value is not None}
    return method, object_points, scene_points, options


def _check_answer(method: str, answer, object_points, scene_points, options) -> None:
    """Finite answers, one per batch element (and per sample), one entry per input point."""
    batch, k = object_points.shape[0], options.get("num_samples")
    expected = {
        "sample_goals": [(batch, k, object_points.shape[1], 3)],
        "predict_poses": [(batch, k, 4, 4)],
        "placement_distribution": [(batch, scene_points.shape[1]), (batch, scene_points.shape[1], 3)],
    }[method]
    answers = answer if isinstance(answer, tuple) else (answer,)
    assert [tuple(a.shape) for a in answers] == expected
    assert all(bool(torch.isfinite(a).all()) for a in answers), f"{method} returned NaN or inf"


@pytest.fixture(scope="module")
def policy():
    torch.set_num_threads(1)
    return tiny_policy()


def test_public_api_works_or_names_the_bad_argument(policy):
    outcomes: Counter = Counter()

    @_settings(examples=1000)
    @given(call=api_calls())
    def check(call):
        method, object_points, scene_points, options = call
        wrong = [name for name, value in options.items() if not _option_is_valid(name, value)]
        wrong += [
            n for n, v in (("object_points", object_points), ("scene_points", scene_points)) if not is_valid_cloud(v)
        ]
        if not wrong and object_points.shape[0] != scene_points.shape[0]:
            wrong = ["object_points and scene_points"]
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", UserWarning)  # the units warning is tested elsewhere
                answer = getattr(policy, method)(object_points, scene_points, **options)
        except (ValueError, TypeError) as error:
            assert wrong, f"{method} refused a valid input: {error}"
            assert any(name in str(error) for name in wrong), f"{error!r} names none of {wrong}"
            outcomes["refused"] += 1
            return
        assert not wrong, f"{method} accepted invalid {wrong}"
        _check_answer(method, answer, object_points, scene_points, options)
        outcomes["answered"] += 1

    start = time.perf_counter()
    check()
    _report("policy API", outcomes, start)
    assert outcomes["answered"] >= 30 and outcomes["refused"] >= 30, "the generator must exercise both outcomes"


@pytest.mark.parametrize("device", ["cpu", "cuda", "cuda:7", "mps", "xpu", "meta", "bogus", "", 0])
def test_the_device_is_available_or_named_as_the_problem(tmp_path, device):
    tiny_policy().save_pretrained(tmp_path)
    try:
        loaded = load_goal_predictor(tmp_path, device=device)
    except (ValueError, TypeError) as error:
        assert "device" in str(error), error
        return
    assert next(loaded.parameters()).device.type == torch.device(device).type


# -------------------------------------------------------------------------------------- converters
_MISSING = object()


def _changed(original: np.ndarray, change: tuple):
    """The field after `change`: ("missing",), ("replace", array), ("scale", factor, non-finite value or None)
    or ("dtype", name); the scaled and retyped copies keep the shape, so rows still correspond."""
    kind = change[0]
    if kind == "missing":
        return _MISSING
    if kind == "replace":
        return change[1]
    if kind == "dtype":
        with np.errstate(over="ignore", invalid="ignore"):
            return np.asarray(original).astype(change[1])
    value = np.asarray(original, dtype=np.float64) * change[1]
    if change[2] is not None:
        value.flat[value.size // 2] = change[2]
    return value


def _rpdiff_file(path: Path, field: str, change: tuple) -> DemoRef:
    demo, _ = rpdiff_demo(np.random.default_rng(0), n_child=64, n_parent=128)
    owner, key = field.split("/")
    value = _changed(demo[owner][key], change)
    demo[owner] = {k: v for k, v in demo[owner].items() if k != key} | ({} if value is _MISSING else {key: value})
    return DemoRef(path.name, save_rpdiff_demo(path, demo))


def _dedo_file(path: Path, field: str, change: tuple) -> DemoRef:
    demo = dedo_goal_demo(np.random.default_rng(0), n_anchor=128)
    value = _changed(demo.pop(field), change)
    return DemoRef(path.name, save_dedo_goal_demo(path, demo | ({} if value is _MISSING else {field: value})))


def _nist_file(path: Path, field: str, change: tuple) -> DemoRef:
    save_nist_npz(path, *nist_demo(np.random.default_rng(0), n_plug=64, n_socket=128)[:3])
    with np.load(path) as archive:
        values = {k: archive[k] for k in archive.files}
    value = _changed(values.pop(field), change)
    np.savez(path, **(values | ({} if value is _MISSING else {field: value})))
    return DemoRef(path.name, path, key="waterproof")


#: source -> (writer of one demo with one field changed, the fields it changes, the reader).
SOURCES = {
    "rpdiff": (
        _rpdiff_file,
        ("multi_obj_start_pcd/child", "multi_obj_start_pcd/parent", "multi_obj_final_pcd/child"),
        lambda demo, opts: rpdiff.demo_episode(demo, opts, (16, 32), "place"),
    ),
    "dedo": (
        _dedo_file,
        ("action_pc", "flow", "anchor_pc"),
        lambda demo, opts: dedo.goal_episode(demo, opts, (16, 32), "hang"),
    ),
    "nist": (_nist_file, nist.NPZ_FIELDS, lambda demo, opts: nist.demo_episode(demo, opts, (16, 32), "auto")),
}


def _as_numpy(array) -> np.ndarray:
    return array.float().numpy() if isinstance(array, torch.Tensor) else array


@st.composite
def broken_demos(draw):
    """(source, field, change, raw bytes or None): one field changed, or the whole file replaced by bytes."""
    source = draw(st.sampled_from(sorted(SOURCES)))
    field = draw(st.sampled_from(SOURCES[source][1]))
    change = draw(
        st.one_of(
            st.tuples(st.just("scale"), st.sampled_from(SCALES), st.sampled_from(NON_FINITE)),
            st.tuples(st.just("dtype"), st.sampled_from([d for d in DTYPES if d != "bfloat16"])),
            st.tuples(st.just("replace"), arrays(points=(0, 2, 3, 16, 40, 200), layouts=LAYOUTS[:5]).map(_as_numpy)),
            st.tuples(st.just("replace"), st.sampled_from(("a string", np.zeros((4, 4)), np.zeros(())))),
            st.just(("missing",)),
        )
    )
    raw = draw(st.one_of(st.none(), st.none(), st.none(), st.binary(max_size=64)))
    return source, field, change, raw


def test_converter_readers_convert_or_name_the_file(tmp_path):
    outcomes: Counter = Counter()
    options = ConversionOptions(frames_per_episode=2)

    @_settings(examples=600)
    @given(case=broken_demos())
    def check(case):
        source, field, change, raw = case
        write, _, read = SOURCES[source]
        demo = write(tmp_path / f"demo_aug_{source}.npz", field, change)
        if raw is not None:
            demo.path.write_bytes(raw)
        try:
            frames = read(demo, options)[0]
        except (ValueError, TypeError) as error:
            assert demo.source in str(error), f"{error!r} does not name {demo.source}"
            outcomes[f"{source} refused"] += 1
            return
        assert all(np.isfinite(value).all() for frame in frames for value in frame.values() if value.dtype.kind == "f")
        outcomes[f"{source} converted"] += 1

    start = time.perf_counter()
    check()
    _report("converter readers", outcomes, start)
    assert all(outcomes[f"{source} converted"] for source in SOURCES), "every source must also convert"
