"""The small Fourier and conventional systems of the reconstruction tests, on one torch thread."""

from __future__ import annotations

import pytest
import torch

from tests.engine.reconstruct.conftest import make_conventional, make_fourier


@pytest.fixture(scope="package", autouse=True)
def _one_torch_thread():
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


@pytest.fixture(scope="package")
def fourier():
    return make_fourier()


@pytest.fixture(scope="package")
def conventional():
    return make_conventional()
