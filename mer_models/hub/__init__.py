"""Models as files: names, cards, the Hugging Face Hub, checksums and the checkpoint folder.

Nothing here builds a network, so the model class (:mod:`mer_models.diffusion.model`) can stand on it:

* :mod:`.names` (validated names, repo ids, revisions), :mod:`.client` (the only door to the Hub),
  :mod:`.integrity` (checksums), :mod:`.card` and :mod:`.render` (model cards), :mod:`.fromckpt`
  (a card from a checkpoint), :mod:`.registry` (zoo name -> card), :mod:`.catalogue` (planned models);
* :mod:`.resolve` - a name, folder or repo id -> a verified local folder; :mod:`.publish` - the reverse;
* :mod:`.checkpoint_files` - the folder format (``config.json`` + ``model.safetensors``), written
  atomically and read strictly;
* :mod:`.pretrained` - ``from_pretrained`` / ``save_pretrained`` / ``push_to_hub`` for any model class.
"""
