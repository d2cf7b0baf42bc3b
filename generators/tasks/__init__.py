"""The benchmark tasks: the kit every task stands on (``base``, ``motions``, ``session``), one module a task,
and the registry (``registry``) that the CLI, the collector and the Gymnasium environments read."""
