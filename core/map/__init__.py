"""The map and the data stages exchange: layers, sensor frames, ground truth, vocabulary, class
priors, instances from labels, and the on-disk format."""
