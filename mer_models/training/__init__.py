"""Training the model: denoising + energy guidance, the teacher, fine-tuning, synthetic data.

* :mod:`.train` (``mer train``) and :mod:`.order` (the order and grouping of training batches);
* :mod:`.teacher` (``mer shards solve``: the optimiser's solution of every training sample);
* :mod:`.finetune` (``mer finetune``: a new robot added to a trained model);
* :mod:`.synthetic` - synthetic training samples generated in code (no data needed).
"""
