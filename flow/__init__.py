"""Optical flow between two frames: estimators behind one interface (:mod:`.estimators`: DIS, the simulator's
exact flow), the images they read (:mod:`.images`: grey conversion, a shared decode cache, texture), the
end-point error and Fl-all of a flow (:mod:`.metrics`), the registry that makes them by name (:mod:`.registry`),
the compact learned flow network
(:mod:`.net`), its supervised training on renders (:mod:`.train`, :mod:`.augment`) and its unsupervised
fine-tuning on real pairs (:mod:`.unsup`).

Imports: core, gen, models (files), torch, opencv; never vo or slam.
"""
