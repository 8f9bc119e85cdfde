"""PyTorch mirror of the subpixel SSR denoiser (DESIGN.md sections 3 and 4).

Modules:
  model   -- config, input preparation, warp, TFA, U-Net, run_sequence, FLOP count
  export  -- deterministic safetensors writer, checked loader, `python -m ssr.export`
  losses  -- the training losses of DESIGN section 4
  golden  -- `python -m ssr.golden --out ../tests/data`: parity cases for the Rust engine
  data    -- dataset folders of `subpixel dataset`: windows, crops, flips, caches, EXR I/O
  synth   -- tiny synthetic datasets (tests, smoke runs)
  metrics -- tonemapped 8-bit PSNR/SSIM, RMSE, relMSE, temporal error (as src/metrics.rs)
  train   -- `python -m ssr.train`: training, checkpoints/resume, torchrun, export
  baselines -- RAE, NSRR (learned), raw input and reprojected accumulation (non-learned)
  evaluate  -- `python -m ssr.evaluate`: predictions as EXR for `subpixel eval` + a table
"""

from .model import SSRConfig, SSRModel, flops_per_pixel, prepare_inputs, warp  # noqa: F401
