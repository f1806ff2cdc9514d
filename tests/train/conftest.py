import pytest
import torch

from dfc.geometry.triangulate import triangulate
from dfc.train.fit import fit_image

from ._scene import scene_curves, scene_image


@pytest.fixture(scope="module", autouse=True)
def one_thread():
    """These tensors are small: one thread avoids torch's inter-thread overhead on a busy 2-core machine
    (measured 10× less CPU time when other processes compete for the cores)."""
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)


@pytest.fixture(scope="module")
def scene_mesh():
    return triangulate(scene_curves(), max_triangles=500)


@pytest.fixture(scope="module")
def fitted(scene_mesh):
    image = scene_image()
    return image, fit_image(image, scene_mesh, steps=300, batch_size=4096, qat_steps=30)
