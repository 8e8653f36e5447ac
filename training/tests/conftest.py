import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from rpnn.synthetic import write_set  # noqa: E402, F401


@pytest.fixture
def record_set(tmp_path):
    return write_set(tmp_path / "data", 1200, 200)
