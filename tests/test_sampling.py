"""``sensor.sampling``: physical pixels (box) versus the paper's point sampling."""

from __future__ import annotations

import pytest
import torch
import torch.nn.functional as F

from optoenc.encoders import imaging as im
from optoenc.encoders.coded_aperture import CodedAperture
from optoenc.encoders.slm import FixedSLM
from optoenc.errors import ConfigError


@pytest.mark.parametrize("n_grid,n_out", [(380, 3), (507, 4), (96, 24), (100, 7), (5, 5), (9, 1)])
def test_point_matrix_is_torchs_bilinear_downsampling_without_antialias(n_grid, n_out):
    # Analytic reference: torch's own bilinear resize (align_corners=False, antialias=False), the
    # paper's published downsampling. Both are the same two-tap sums in float64: agreement to 1e-12.
    torch.manual_seed(0)
    img = torch.rand(1, 1, n_grid, 2 * n_grid, dtype=torch.float64)
    ref = F.interpolate(img, size=(n_out, 2 * n_out), mode="bilinear", align_corners=False, antialias=False)
    ours = im.integrate(img, (n_out, 2 * n_out), sampling="point")
    torch.testing.assert_close(ours, ref, rtol=0, atol=1e-12)


def test_point_sampling_aliases_where_box_integration_averages():
    # Grid-scale stripes (rows alternate 0 / 1), 60 rows read by 4 pixels of 15 rows: a physical
    # pixel averages 7 or 8 bright rows of 15 (0.5 +- 1/30); a point sample lands on one row
    # (source coordinate 7, 22, 37, 52: integers) and returns 0 or 1: pure aliasing.
    n = 60
    stripes = (torch.arange(n) % 2).to(torch.float64)[:, None].expand(n, n)[None, None]
    box = im.integrate(stripes, (4, 4), sampling="box")
    point = im.integrate(stripes, (4, 4), sampling="point")
    assert (box - 0.5).abs().max() <= 1 / 30 + 1e-12
    torch.testing.assert_close((point - 0.5).abs(), torch.full_like(point, 0.5), rtol=0, atol=1e-12)


def test_sampling_rows_are_partitions_of_unity_and_unknown_kinds_are_refused():
    for kind in im.SAMPLINGS:
        m = im.sampling_matrix(50, 7, kind)
        torch.testing.assert_close(m.sum(1), torch.ones(7, dtype=torch.float64), rtol=0, atol=1e-12)
        assert (m >= 0).all()
    with pytest.raises(ConfigError, match="sensor.sampling"):
        im.sampling_matrix(50, 7, "nearest")


@pytest.mark.parametrize("cls", [FixedSLM, CodedAperture])
def test_point_sampled_encoder_operator_equals_its_direct_pipeline(cls):
    # The operator path (correlation tensors) and the direct path (place, FFT, sample) are two
    # implementations of one linear map: they agree to float64 round-off (1e-10 relative).
    enc = cls(sensor={"embedding": (3, 4), "sampling": "point"}, fidelity={"preset": "fast", "dtype": "float64"})
    torch.manual_seed(1)
    x = torch.rand(2, 1, 28, 28, dtype=torch.float64)
    a = enc.measure(x, method="operator")
    b = enc.measure(x, method="direct")
    torch.testing.assert_close(a, b, rtol=1e-10, atol=1e-10 * float(b.abs().max()))
    box = cls(sensor={"embedding": (3, 4)}, fidelity={"preset": "fast", "dtype": "float64"})
    # Different sensors: the embeddings differ by far more than round-off.
    assert (box.measure(x) - a).abs().max() > 1e-3 * a.abs().max()
