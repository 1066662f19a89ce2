"""fixer4d.eval: image metrics (PSNR, DSSIM1/2, LPIPS-alex) and the held-out evaluation protocol."""
