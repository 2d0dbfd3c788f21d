"""The guided search of a lost stretch (recon.guided): contrast of either polarity, one path under a step bound."""
import numpy as np
import pytest
from fast_oracles import best_path as best_path_oracle
from hypothesis import given, settings, strategies as st

from recon.guided import best_path, ray_candidates, ray_points, strongest_candidates, tube_contrast


def _tube_image(polarity: float, radius_px: float = 2.0, noise: float = 1.0, seed: int = 0):
    """A horizontal tube at y = 40 on noise, plus a one-sided step (a backdrop edge) at x >= 60."""
    rng = np.random.default_rng(seed)
    img = rng.normal(0.0, noise, (80, 100)).astype(np.float32)
    y = np.arange(80)[:, None]
    img[:, :50] += np.where(np.abs(y - 40) <= radius_px, polarity * 12.0, 0.0)
    img[:, 60:] += np.where(y >= 20, 15.0, 0.0)  # an edge: brighter on one side only
    return img


@pytest.mark.parametrize("polarity", [1.0, -1.0])
def test_contrast_finds_a_tube_of_either_polarity_and_not_an_edge(polarity):
    img = _tube_image(polarity)
    normals = np.tile([0.0, 1.0], (3, 1))
    on_tube = np.array([[20.0, 40.0], [30.0, 40.0], [40.0, 40.0]])
    on_edge = np.array([[70.0, 20.0], [80.0, 20.0], [90.0, 20.0]])
    # Most readings on backdrop, so the robust scale is the noise's.
    backdrop = np.column_stack([np.linspace(5, 45, 60), np.full(60, 10.0)])
    uv = np.vstack([on_tube, on_edge, backdrop])
    c = tube_contrast(img, (0, 0), uv, np.vstack([normals, normals, np.tile([0.0, 1.0], (60, 1))]), 2.0)
    assert np.all(c[:3] > 5.0)
    assert np.all(c[3:6] < 1.0)


def test_contrast_reads_the_box_at_its_origin():
    img = _tube_image(1.0)
    uv = np.array([[120.0, 240.0]])  # the tube, in a box whose top-left pixel is (100, 200)
    far = np.column_stack([np.linspace(105, 145, 40), np.full(40, 210.0)])
    c = tube_contrast(img, (100, 200), np.vstack([uv, far]), np.tile([0.0, 1.0], (41, 1)), 2.0)
    assert c[0] > 5.0


def test_contrast_of_more_points_than_one_remap_takes():
    """Over 32767 points (cv2.remap's limit on a map's rows): 100 points repeated 400 times read as the 100 do."""
    img = _tube_image(1.0)
    rng = np.random.default_rng(1)
    uv = np.column_stack([rng.uniform(5, 45, 100), rng.uniform(10, 70, 100)])
    uv[:10, 1] = 40.0  # some on the tube
    nrm = np.tile([0.0, 1.0], (100, 1))
    once = tube_contrast(img, (0, 0), uv, nrm, 2.0)
    many = tube_contrast(img, (0, 0), np.tile(uv, (400, 1)), np.tile(nrm, (400, 1)), 2.0)
    assert np.all(once[:10] > 5.0)
    np.testing.assert_allclose(many, np.tile(once, 400), rtol=1e-5, atol=1e-5)


@settings(max_examples=20, deadline=None)
@given(st.integers(0, 10_000))
def test_best_path_follows_the_scored_path_under_the_step_bound(seed):
    rng = np.random.default_rng(seed)
    K, n = 12, 9
    start = np.zeros(3)
    # Candidates on rays parallel to z at x = 1..K; the true path at index 4, a decoy that jumps from 0 to 8.
    pts = np.array([[[k + 1.0, 0.0, (j - 4) * 2.0] for j in range(n)] for k in range(K)])
    score = rng.normal(0.0, 0.1, (K, n))
    score[:, 4] += 1.0
    score[::2, 0] += 1.6  # high but only every other ray: reaching it means jumping 8 mm along a 1 mm step
    score[1::2, 8] += 1.6
    path = best_path(score, pts, np.ones(K), start, stretch_cost=1.0, max_stretch=4.0)
    assert path is not None
    assert np.all(path == 4)


def test_best_path_is_none_where_no_candidate_is_reachable():
    pts = np.array([[[0.0, 0.0, 50.0], [0.0, 0.0, 60.0]]] * 3) + np.arange(3)[:, None, None] * [1.0, 0, 0]
    assert best_path(np.ones((3, 2)), pts, np.ones(3), np.zeros(3), max_stretch=4.0) is None


def test_ray_candidates_lie_on_the_rays_within_reach():
    center = np.array([0.0, 0.0, -300.0])
    dirs = np.array([[0.0, 0.0, 1.0], [0.1, 0.0, 1.0]])
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    start = np.array([5.0, 0.0, 0.0])
    reach = np.array([10.0, 40.0])
    pts = ray_candidates(center, dirs, start, reach, 7)
    assert pts.shape == (2, 7, 3)
    for k in range(2):
        off_ray = np.cross(pts[k] - center, dirs[k])
        assert np.allclose(off_ray, 0.0, atol=1e-9)
        assert np.all(np.linalg.norm(pts[k] - start, axis=1) <= reach[k] + 1e-6)


def test_strongest_candidates_keep_a_narrow_crossing_between_the_evenly_spaced_ones():
    """A tube crossing a ray reads high over a few dense candidates; the evenly spaced subset steps over it."""
    rng = np.random.default_rng(3)
    contrast = rng.uniform(0.0, 1.0, (4, 1000))
    contrast[:, 503:506] = [6.0, 9.0, 6.0]   # the crossing: between the even candidates 501 and 505.x
    contrast[3] = 0.0                        # a ray with no maximum at all
    pick = strongest_candidates(contrast, 10, 5)
    assert pick.shape == (4, 15)
    even = np.round(np.linspace(0, 999, 10)).astype(int)
    assert np.all(pick[:, :10] == even) and 504 not in even
    assert np.all(pick[:3, 10] == 504)       # the strongest maximum first
    assert np.all((pick >= 0) & (pick < 1000))


def test_ray_points_share_one_depth_grid():
    center = np.array([1.0, 2.0, -300.0])
    dirs = np.array([[0.0, 0.0, 1.0], [0.6, 0.0, 0.8]])
    pts = ray_points(center, dirs, 250.0, 350.0, 11)
    depth = np.einsum("knd,kd->kn", pts - center, dirs)
    np.testing.assert_allclose(depth, np.tile(np.linspace(250.0, 350.0, 11), (2, 1)))


@settings(max_examples=25, deadline=None)
@given(st.integers(0, 10_000), st.integers(2, 30), st.integers(1, 40))
def test_compiled_best_path_equals_its_numpy_oracle(seed, K, n):
    """Scores with ties (rounded), candidates some of which no step reaches, a start near the first ray."""
    rng = np.random.default_rng(seed)
    pts = np.cumsum(rng.normal(0.0, 1.0, (K, 1, 3)), axis=0) + rng.normal(0.0, 2.0, (K, n, 3))
    score = np.round(rng.normal(0.0, 1.0, (K, n)), 1)
    step = rng.uniform(0.3, 1.5, K)
    start = pts[0, 0] + rng.normal(0.0, 1.0, 3)
    for cost, stretch in ((0.25, 12.0), (1.0, 2.0)):
        got = best_path(score, pts, step, start, stretch_cost=cost, max_stretch=stretch)
        want = best_path_oracle(score, pts, step, start, stretch_cost=cost, max_stretch=stretch)
        assert (got is None) == (want is None)
        if want is not None:
            np.testing.assert_array_equal(got, want)
