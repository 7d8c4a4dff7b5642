"""Stage 6: post-processing of point chunks: invalid-point filter, semantic checks, subsampling, running statistics."""
