import os
import sys

import pytest
import torch

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

from ssr.golden import make_frames  # noqa: E402

torch.set_num_threads(min(2, torch.get_num_threads()))

H, W = 24, 40


@pytest.fixture
def frames():
    """3 consecutive random frames at 40x24 (the golden inputs)."""
    return make_frames(height=H, width=W, count=3)
