"""Priors of a run: depth, dynamic masks and intrinsics, from files, pretrained models or the video itself
(weight-free defaults). See :mod:`trackingworld.priors.resolve`."""
