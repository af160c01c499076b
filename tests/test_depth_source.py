"""Conformance of every depth source to companion.depth_source's contract (issue 11 item 5).

The implementations are discovered, not listed (issue 33): every class of ours with
``compute(...) -> DepthMap`` (``_contracts.implementations``) runs through every test
here, and ``test_every_depth_source_has_a_conformance_entry`` fails for one that has no
entry in ``SOURCES`` (how to build it and what frames it reads). A depth camera (issue 35)
is a source too: its frames are depth frames made from the renderer's true depth by
plant-sim's RealSense-like camera model; ground truth (the lockstep bench's) reads blank
pairs and is handed the renderer's true depth. The matcher-only physics (textureless
surfaces) is checked on the matchers; the depth camera has its counterpart in
``test_depth_camera.py``.
"""

from __future__ import annotations

import enum
import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import pytest
from _contracts import check_coverage, implementations

from companion.bare_bm import BareStereoBM
from companion.depth_camera import DepthCameraConfig, DepthCameraSource
from companion.depth_source import DISP_SCALE, DepthMap, DepthSource
from companion.perception import PerceptionConfig, StereoPerception
from companion.stereo_bm import PaddedStereoBM
from evaluation.truth_perception import TruthDepthSource
from plant_sim.depth_camera import DepthNoiseParams, depth16_from_truth
from plant_sim.stereo_camera import StereoCameraRenderer
from plant_sim.world import Box, GroundPlane, Material, Sphere, World
from protocols.camera import CameraModel
from protocols.stereo_frame import DepthFrame, PixelEncoding, StereoFrame

CAMERA = CameraModel()
LEVEL = np.eye(3)
POS = np.array([0.0, 0.0, -7.0])


class Feed(enum.Enum):
    """What frames a source reads."""

    PAIR = "rectified stereo pair"
    DEPTH_FRAME = "depth camera frame"
    TRUTH = "blank pair, the true depth handed over with provide()"


@dataclass(frozen=True)
class Entry:
    build: Callable[[], DepthSource]
    feed: Feed


DEPTH_CAMERA = DepthCameraConfig(min_range_m=1.0)  # plant-sim's camera (DepthNoiseParams)
SOURCES = {
    "companion.stereo_bm.PaddedStereoBM": Entry(
        lambda: PaddedStereoBM(PerceptionConfig()), Feed.PAIR
    ),
    "companion.bare_bm.BareStereoBM": Entry(lambda: BareStereoBM(PerceptionConfig()), Feed.PAIR),
    "companion.depth_camera.DepthCameraSource": Entry(
        lambda: DepthCameraSource(DEPTH_CAMERA), Feed.DEPTH_FRAME
    ),
    "evaluation.truth_perception.TruthDepthSource": Entry(
        lambda: TruthDepthSource(PerceptionConfig()), Feed.TRUTH
    ),
}
DISCOVERED = implementations("compute", "DepthMap")
MATCHERS = [name for name in DISCOVERED if name in SOURCES and SOURCES[name].feed is Feed.PAIR]


def _qualname(cls: type) -> str:
    return f"{cls.__module__}.{cls.__qualname__}"


def _build(name: str) -> DepthSource:
    if name not in SOURCES:
        pytest.fail(f"{name} implements compute() -> DepthMap but has no entry in SOURCES")
    return SOURCES[name].build()


@pytest.fixture(scope="module", params=DISCOVERED)
def source(request) -> DepthSource:
    return _build(request.param)


@pytest.fixture(scope="module", params=MATCHERS)
def stereo_source(request) -> DepthSource:
    return _build(request.param)


@pytest.fixture(scope="module")
def renderer() -> StereoCameraRenderer:
    return StereoCameraRenderer(CAMERA)


def _feed(source) -> Feed:
    return SOURCES[_qualname(type(source))].feed


def test_every_depth_source_has_a_conformance_entry():
    """Discovery finds the four we know, every one it finds has an entry (and no entry
    names a class that is no longer a depth source), and each entry builds its class."""
    check_coverage(DISCOVERED, SOURCES, "depth sources (compute() -> DepthMap)", 4)
    for name, entry in SOURCES.items():
        assert _qualname(type(entry.build())) == name


def test_discovery_finds_implementations_and_their_subclasses(tmp_path):
    """On a tree made for the purpose: the contract (a Protocol), an implementation, its
    subclass in another module, a string annotation; not a look-alike returning else."""
    pkg = tmp_path / "pkg"
    pkg.mkdir()
    (pkg / "__init__.py").write_text("")
    (pkg / "contract.py").write_text(
        "class Source(Protocol):\n    def compute(self, frame) -> DepthMap: ...\n"
    )
    (pkg / "a.py").write_text(
        "class A:\n    def compute(self, frame) -> DepthMap: ...\n"
        "class Other:\n    def compute(self, frame) -> float: ...\n"
        "class Quoted:\n    def compute(self, frame) -> 'x.DepthMap | None': ...\n"
    )
    (pkg / "b.py").write_text("from pkg.a import A\nclass B(A):\n    pass\n")
    found = implementations("compute", "DepthMap", root=tmp_path, searched=("pkg",))
    assert found == ["pkg.a.A", "pkg.a.Quoted", "pkg.b.B"]


def _frame(renderer, world, pos=POS, R=LEVEL, seed=0, source=None):
    """The frame ``source`` reads (a pair, a depth frame from plant-sim's depth camera, or
    a blank pair whose true depth the source is handed) of the view from ``pos``, and the
    true depth."""
    out = renderer.render(world, pos, R, noise_seed=seed)
    feed = _feed(source) if source is not None else Feed.PAIR
    if feed is Feed.DEPTH_FRAME:
        plane = depth16_from_truth(out.depth_left_m, CAMERA.intrinsics, DepthNoiseParams(), seed)
        frame = DepthFrame(seed, seed, CAMERA.intrinsics, plane, PixelEncoding.DEPTH16, 0.001)
        return frame, out.depth_left_m
    if feed is Feed.TRUTH:
        source.provide(seed, out.depth_left_m)
        blank = np.zeros_like(out.left)
        return StereoFrame(seed, seed, CAMERA.intrinsics, blank, blank), out.depth_left_m
    return StereoFrame(seed, seed, CAMERA.intrinsics, out.left, out.right), out.depth_left_m


def _range_m(source, frame) -> float:
    """The source's farthest range for this frame (the contract's ``max_range_m``)."""
    if _feed(source) is Feed.DEPTH_FRAME:
        return source.config.range_m(frame.intrinsics)
    return PerceptionConfig().max_range_m


def check_contract(frame, dm: DepthMap, max_range_m: float) -> None:
    """The contract's invariants that hold for any frame (companion.depth_source): Eq. 27
    exactly for a matcher; for a depth camera the disparity is the depth's equivalent,
    rounded to 1/16 px."""
    shape = (frame.intrinsics.height_px, frame.intrinsics.width_px)
    assert isinstance(dm, DepthMap)
    assert dm.disparity_fixed.shape == shape and dm.disparity_fixed.dtype == np.int16
    assert dm.depth_m.shape == shape and dm.depth_m.dtype == np.float32
    assert not dm.depth_m.flags.writeable
    fb = frame.intrinsics.focal_baseline_m_px
    d_far = max(1, math.ceil(DISP_SCALE * fb / max_range_m))
    disp, depth = dm.disparity_fixed, dm.depth_m
    finite = np.isfinite(depth)
    np.testing.assert_array_equal(finite, disp >= d_far, err_msg="finite <=> within range")
    if isinstance(frame, DepthFrame):
        equivalent = DISP_SCALE * fb / depth[finite].astype(np.float64)
        # rounding to 1/16 px, plus float32's 2**-24 of the depth at int16 disparities
        np.testing.assert_allclose(disp[finite], equivalent, atol=0.5 + 32767 * 2.0**-23)
    else:
        np.testing.assert_allclose(
            depth[finite], DISP_SCALE * fb / disp[finite].astype(np.float64), rtol=1e-6
        )
    far = np.isinf(depth)
    assert np.all(depth[far] > 0)
    assert np.all((disp[far] >= 0) & (disp[far] < d_far)), "+inf only for a far match"
    assert not far[:, : dm.blind_band_px].any(), "no +inf in the blind band"
    c = dm.counts
    assert c.n_valid == np.count_nonzero(finite)
    assert c.n_valid + c.n_unmatched + c.n_beyond_range == depth.size
    assert c.n_beyond_range >= np.count_nonzero(far)
    assert 0 <= c.n_too_near <= c.n_valid and 0 <= c.n_coarse <= c.n_valid
    assert dm.blind_band_px >= 0


def test_is_a_depth_source(source):
    assert isinstance(source, DepthSource)
    perception = StereoPerception(source=source)  # plugs into the pipeline as it is
    assert perception.source is source


def test_textured_plane_is_ranged_by_eq27(renderer, source):
    """A textured wall 3 m ahead filling the view: the contract holds, and right of the
    blind band >= 80 % of the pixels are ranged with a median error below 1 %."""
    wall = Box((3.1, 0.0, -7.0), (0.2, 40.0, 40.0))
    frame, truth = _frame(renderer, World(boxes=(wall,), ground=None), source=source)
    dm = source.compute(frame)
    check_contract(frame, dm, _range_m(source, frame))
    seen = np.zeros(truth.shape, bool)
    seen[8:-8, dm.blind_band_px : -8] = True  # OpenCV leaves half a block at the border
    ranged = seen & np.isfinite(dm.depth_m)
    assert ranged.sum() >= 0.8 * seen.sum(), ranged.sum() / seen.sum()
    rel = np.abs(dm.depth_m[ranged] - truth[ranged]) / truth[ranged]
    assert np.median(rel) < 0.01, np.median(rel)
    assert np.percentile(rel, 99) < 0.1, np.percentile(rel, 99)


def test_what_the_right_camera_cannot_see_is_never_finite(renderer, source):
    """A wall-sized sphere 2.5 m ahead: where its surface lies left of the right image
    (true disparity > column), nothing can be measured."""
    world = World(spheres=(Sphere((10.0, 0.0, -7.0), 7.5),), ground=None)
    frame, truth = _frame(renderer, world, source=source)
    dm = source.compute(frame)
    check_contract(frame, dm, _range_m(source, frame))
    fb = CAMERA.intrinsics.focal_baseline_m_px
    hidden = fb / truth > np.arange(CAMERA.width_px)[None, :]
    assert hidden.sum() > 1000
    assert not np.isfinite(dm.depth_m[hidden]).any()


@pytest.mark.parametrize("seed", range(4))
def test_textureless_wall_certifies_no_free_space(renderer, stereo_source, seed):
    """A textureless wall filling the view: (almost) nothing is ranged, and no pixel claims
    "nothing nearer than max range" (+inf) through it, whatever the sensor noise does."""
    wall = Box((10.0, 0.0, -7.0), (0.2, 30.0, 14.0), material=Material.TEXTURELESS)
    world = World(boxes=(wall,), ground=GroundPlane(0.0))
    pos = np.array([11.0 + 0.9 * seed, 0.0, -7.0])
    R = np.diag([-1.0, -1.0, 1.0])  # facing south, towards the wall
    frame, truth = _frame(renderer, world, pos, R, seed=seed)
    assert np.all(np.isfinite(truth))  # the wall fills the view
    dm = stereo_source.compute(frame)
    check_contract(frame, dm, _range_m(stereo_source, frame))
    assert not np.isinf(dm.depth_m).any()
    known = np.isfinite(dm.depth_m)
    assert known.mean() < 0.05
    assert np.all(dm.depth_m[known] <= 1.1 * truth[known])


def test_sky_is_far_and_ground_is_ranged(renderer, source):
    """Ground and sky: ranged ground within range, +inf (known free) for matched sky and far
    ground outside the blind band, never a finite depth beyond max range."""
    frame, truth = _frame(
        renderer, World(ground=GroundPlane(0.0)), np.array([0.0, 0.0, -2.0]), source=source
    )
    dm = source.compute(frame)
    check_contract(frame, dm, _range_m(source, frame))
    assert np.isinf(dm.depth_m).mean() > 0.03  # matched sky (its clouds) or far ground
    near_ground = np.isfinite(truth) & (truth < 10.0)
    ranged = near_ground & np.isfinite(dm.depth_m)
    assert ranged.sum() > 0.5 * near_ground[:, dm.blind_band_px :].sum()


def test_deterministic(renderer, source):
    frame, _ = _frame(renderer, World(spheres=(Sphere((4.5, 0.0, -7.0), 1.5),)), source=source)
    a, b = source.compute(frame), source.compute(frame)
    np.testing.assert_array_equal(a.disparity_fixed, b.disparity_fixed)
    np.testing.assert_array_equal(a.depth_m, b.depth_m)
    assert a.counts == b.counts and a.blind_band_px == b.blind_band_px


@pytest.mark.parametrize("size", [(1, 1), (8, 4), (33, 200), (321, 17)])
def test_any_frame_size_gives_a_depth_map(source, size):
    width, height = size
    k = CameraModel(width_px=width, height_px=height).intrinsics
    rng = np.random.default_rng(width * 1000 + height)
    image = rng.integers(0, 256, (height, width), dtype=np.uint8)
    frame = StereoFrame(0, 0, k, image, image)
    if _feed(source) is Feed.DEPTH_FRAME:
        depth = rng.integers(0, 40_000, (height, width), dtype=np.uint16)
        frame = DepthFrame(0, 0, k, depth, PixelEncoding.DEPTH16, 0.001, image)
    elif _feed(source) is Feed.TRUTH:  # sky, unknown and surfaces from 0.1 m to 100 m
        depth_m = np.exp(rng.uniform(math.log(0.1), math.log(100.0), (height, width)))
        depth_m[rng.random((height, width)) < 0.1] = np.inf
        depth_m[rng.random((height, width)) < 0.05] = np.nan
        source.provide(0, depth_m)
    check_contract(frame, source.compute(frame), _range_m(source, frame))
