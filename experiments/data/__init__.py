"""Recordings and weights on disk: where a configured recording lies and its frame range
(:mod:`.datasets`), the generated exact-truth recording (:mod:`.scale_truth`), the frames'
download (:mod:`.download`) over one verified, resumable HTTP file (:mod:`.fetch`), the YOLO
weights (:mod:`.weights`), and both fetched on a machine's first run (:mod:`.first_run`)."""
