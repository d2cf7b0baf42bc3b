"""The encoder-pretraining corpus: the 14 procedural indenter shapes (``shapes``), their scene (``scene``) and
the episode script (``corpus``)."""
