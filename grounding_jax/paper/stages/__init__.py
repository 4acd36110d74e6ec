"""The package's own stages, one experiment per module (each defines ``STAGE``, a
`grounding_jax.paper.stage.Stage`); `grounding_jax.paper.stage.stages` finds them."""
