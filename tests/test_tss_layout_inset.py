"""The inset L-packing lattice (``layout.lp_inset_offset``, issue 50 part 1): ``tss``'s samples moved off the
triangle's edges, so that none is one a neighbouring triangle shades again, read back exactly for linear shading."""

from __future__ import annotations

import numpy as np
import pytest

from splitrender.methods.tss.layout import (lp_inset_coords, lp_inset_offset, lp_positions, lp_reconstruct, tess_coords,
                                            tip_dim, v_count)


@pytest.mark.parametrize("lv", [1, 2, 3, 4, 5, 8, 9, 13, 16, 33, 63, 64])
def test_inset_lattice_is_off_the_edges_and_read_back_exactly_for_linear_shading(lv: int) -> None:
    """At ``inset`` 1 every one of the ``v(l)`` samples is at least ``1 / (3 (l + 1))`` inside the triangle (the
    paper's lattice puts ``3 l`` of them on the edges), and the client's decode (``layout.lp_reconstruct``, mirrored
    by ``shaders/client.frag``), extrapolating past the outer ring, reproduces a linear function of the barycentrics
    to rounding everywhere in the triangle, its edges and corners included.  The same blocks read as the paper's
    lattice are off (measured: max error 1.0 at level 1, 0.031 at level 64, for a function of range 3.7), so the
    test tells the two decodes apart."""
    rng = np.random.default_rng(2)
    c = np.array([0.3, 1.7, -2.0])
    B = tess_coords(lv)
    assert len(B) == int(v_count(lv))
    S = lp_inset_coords(B, lv, 1.0)
    d0 = float(lp_inset_offset(lv, 1.0))
    assert np.allclose(S.sum(axis=1), 1.0) and S.min() >= d0 - 1e-12 and d0 == pytest.approx(1.0 / (3.0 * (lv + 1)))
    assert (B.min(axis=1) < 1e-12).sum() == 3 * lv          # the paper's lattice: 3 l samples on the edges
    D = int(tip_dim(lv))
    img = np.full((3, D, D), np.nan)
    for i, t, x, y in lp_positions(B, lv):
        img[t, y, x] = S[i] @ c
    img = np.nan_to_num(img)      # never read with a weight (the odd levels' empty corner)
    edge = rng.dirichlet([1, 1, 1], 600)
    edge[np.arange(600), rng.integers(0, 3, 600)] = 0.0
    edge /= edge.sum(axis=1, keepdims=True)
    P = np.concatenate([rng.dirichlet([1, 1, 1], 4000), B, S, np.eye(3), edge])
    err = np.abs(lp_reconstruct(img, P, lv, inset=1.0) - P @ c)
    assert err.max() < 1e-9, (lv, err.max())
    paper = np.abs(lp_reconstruct(img, P, lv) - P @ c).max()
    assert paper > 0.02, (lv, paper)


def test_the_inset_is_a_checked_config_field() -> None:
    """``lp_inset`` is a :class:`TssConfig` field (off by default), in [0, 1] half ring spacings, a named error outside."""
    from splitrender.errors import ConfigError
    from splitrender.methods.tss.config import TssConfig

    assert TssConfig().lp_inset == 0.0 and TssConfig(lp_inset=1.0).lp_inset == 1.0
    for bad in (-0.1, 1.5, float("nan")):
        with pytest.raises(ConfigError, match="TssConfig.lp_inset: must be in"):
            TssConfig(lp_inset=bad)
