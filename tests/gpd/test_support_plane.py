"""support_plane_mask: every point within the distance of the table plane is masked, nothing above it."""

from __future__ import annotations

import numpy as np

from graspd.gpd.preprocess import support_plane_mask


def test_noisy_table_is_masked_to_its_edges_and_the_object_is_not() -> None:
    rng = np.random.default_rng(0)
    xy = rng.uniform(-0.2, 0.2, (20_000, 2))
    table = np.column_stack([xy, np.clip(rng.normal(0.0, 0.003, len(xy)), -0.007, 0.007)])  # depth noise, 40 cm
    box = np.column_stack([rng.uniform(-0.03, 0.03, (3000, 2)), rng.uniform(0.02, 0.1, 3000)])
    mask = support_plane_mask(np.vstack([table, box]).astype(np.float32), distance=0.01)
    assert mask[: len(table)].all(), f"{int((~mask[: len(table)]).sum())} table points left out"
    assert not mask[len(table):].any()
