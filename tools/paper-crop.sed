# The paper job's crop (issue 15): a centred 306 x 256 crop of the 1224 x 1025 camera at
# the paper's pixel (the job's [camera] and [render] sizes cut). Applied to
# scenes/paper-dataset.toml, or a job made from it, by `sed -f`; used by tools/bench-ab,
# bench-paper-spp, bench-paper-rate and gpu-checks (SMALL=1).
s/^width = 1224/width = 306/
s/^height = 1025/height = 256/
