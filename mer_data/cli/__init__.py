"""Command-line pieces of mer_data; the ``mer`` entry point (mer_models.cli) assembles them."""
