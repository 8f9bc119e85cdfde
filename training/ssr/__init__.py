"""PyTorch mirror of the subpixel SSR denoiser (DESIGN.md sections 3 and 4).

Modules:
  model   -- config, input preparation, warp, TFA, U-Net, run_sequence, FLOP count
  export  -- deterministic safetensors writer, checked loader, `python -m ssr.export`
  losses  -- the training losses of DESIGN section 4
  golden  -- `python -m ssr.golden --out ../tests/data`: parity cases for the Rust engine
"""

from .model import SSRConfig, SSRModel, flops_per_pixel, prepare_inputs, warp  # noqa: F401
