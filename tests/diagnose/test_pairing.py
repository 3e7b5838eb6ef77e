"""The shuffle match of handeye.diagnose.pairing: the signature costs from binary searches equal the direct
all-differences definition (a pose file may hold more views than the images)."""

import numpy as np
import pytest

from handeye.diagnose.pairing import signature_costs


@pytest.mark.parametrize("n_images,n_poses", [(5, 5), (12, 15), (40, 40)])
def test_signature_costs_equal_the_nearest_angle_means(n_images, n_poses):
    rng = np.random.default_rng(n_images)
    sig_c = np.sort(rng.uniform(0, 180, (n_images, n_images - 1)), axis=1)
    sig_m = np.sort(rng.uniform(0, 180, (n_poses, n_poses - 1)), axis=1)
    sig_m[1, : n_images - 1] = sig_c[0]  # a pose whose angles hold all of an image's: cost 0 there
    sig_m[1] = np.sort(sig_m[1])
    direct = np.array(
        [[np.mean(np.min(np.abs(c[:, None] - m[None, :]), axis=1)) for m in sig_m] for c in sig_c]
    )  # shape (N, P)
    got = signature_costs(sig_c, sig_m)
    assert got.shape == (n_images, n_poses)
    assert np.array_equal(got, direct)
    assert got[0, 1] == 0.0
