"""Training data of the flow -> 6DoF network: single frames with depth, motion samplers, synthetic flow from
single frames (the paper's data), supervised frame pairs, toy plane flow, the tensor samples they become and
the network inputs computed ahead of inference."""
