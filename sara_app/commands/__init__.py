"""Sub-commands of ``sara-app``: one module per command group, discovered at start-up.

Each module defines ``register(sub)`` that adds its parsers to the ``argparse`` sub-parsers and
sets ``run=<callable(args) -> int | None>`` as the parser default. Modules import heavy
dependencies inside their run functions so ``sara-app --help`` stays fast.
"""
