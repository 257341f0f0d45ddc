"""World-centric lifting: track labels, stage 1 (poses), stage 2 (bundle adjustment with offsets),
stage 3 (dynamic tracks), densification."""
