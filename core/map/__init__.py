"""The map and the data stages exchange: layers, sensor frames, ground truth, vocabulary, class priors, on-disk format."""
