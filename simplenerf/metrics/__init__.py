"""Image and depth metrics (PSNR, SSIM, LPIPS, depth MAE and SROCC), full-frame and masked; they import no other part
of the package."""
