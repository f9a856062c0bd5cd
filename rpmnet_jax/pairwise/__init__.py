"""One pair of clouds: :func:`rpmnet_jax.align` (``alignment``) — prepare (``prepare``) → starts (``starts``:
classical hypotheses, the network; ``global_search``: the network from rotation hypotheses) → refine and score
each (``candidates``) → select → report; its options (``options``)."""
