//! Zero-mean noise of equal standard deviation in Gaussian, centred exponential and Laplace shapes.
