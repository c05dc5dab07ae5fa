"""Test-suite settings: one torch thread (the small nets run fastest so, and results do not depend on the core count)."""

import torch

torch.set_num_threads(1)
