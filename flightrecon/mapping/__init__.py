"""Online 2DGS mapping: the Gaussian map store, initialization from RGB-D frames, the training loss,
the online optimizer with replay, and PLY persistence."""
