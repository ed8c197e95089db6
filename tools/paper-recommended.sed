# The paper job's recommended [render] setting (docs/dataset.md, "Job file"): applied to
# scenes/paper-dataset.toml by `sed -f`, it adds the analytic direct light with 32 extra
# camera rays (each image that samples past its first check chooses its own there, up
# to 64), 1 light and 4 BSDF samples at the first hit, and samples chosen per pixel
# from the noise target (8.5, first check at 2, then every 4, variance shared over 9 x 9
# pixels). Used by tools/bench-ab and tools/bench-paper-rate.
s/^spp = 256/spp = 256\ndirect_light = "analytic"\nanalytic_rays = 32\nanalytic_rays_max = 64\nlight_samples = 1\nbsdf_samples = 4\nnoise_target = 8.5\nmin_spp = 2\nbatch_spp = 4\nadaptive_radius = 4/
