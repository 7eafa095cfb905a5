"""The guided-diffusion model: ``D(x, sigma, C)`` and how it is sampled.

* :mod:`.network` and :mod:`.attention` - the two transformer decoders over skeleton graphs;
* :mod:`.representation` - the model's canonical frame and diffusion-space scaling;
* :mod:`.edm` - EDM preconditioning and noise; :mod:`.model` - :class:`~.model.RetargetModel`;
* :mod:`.sampling` - the samplers; :mod:`.precision` - where bfloat16 runs natively.
"""
