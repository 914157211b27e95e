"""Shared test settings: one torch thread per test process.

The suite runs as two pytest-xdist workers on two cores; more threads per worker only contend.
"""

import pytest
import torch


@pytest.fixture(autouse=True)
def one_thread():
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)
