"""Reusable scene pieces: the tactile gripper (MJCF), the stepped and recorded simulation, pose arithmetic,
the atomic primitives, scene cameras, and turning recorded frames into an episode.

Imports go one way: ``tasks`` and ``indenters`` use ``scene``; ``scene`` uses ``tactile``; nothing here
imports a task or the indenter corpus.
"""
