"""Pure jax.numpy building blocks: rigid transforms, grouping, point-pair features, Sinkhorn, Procrustes."""
