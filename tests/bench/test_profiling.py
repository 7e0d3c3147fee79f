"""wdss.bench.profiling: a forward's time sorted by kind of work."""

from __future__ import annotations

import torch

from wdss.bench import profiling


def test_profile_buckets_sort_work_by_what_ran():
    """Eager and compile: torch's operators by self time (a convolution's dispatch layers are not counted twice)."""
    import torch.nn.functional as F

    x, w = torch.rand(1, 8, 32, 32), torch.rand(8, 8, 3, 3)
    spent = profiling.profile_buckets(lambda: F.pixel_shuffle(F.conv2d(x, w, padding=1), 2).sin(), "eager", calls=2)
    assert set(spent) == set(profiling.PROFILE_BUCKETS)
    assert spent["convolution"] > 0 and spent["data movement"] > 0 and spent["other"] > 0  # conv, shuffle, sin
    assert spent["generated"] == 0
