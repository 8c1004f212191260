"""Pure batched tensor kernels (installed as ``torchhand.kernels``).

Modules here import only ``torch`` and ``math``: nothing of torchhand's orchestration, nothing of rendering.
Every kernel takes one explicit leading batch dimension ``B``; shapes and units are documented per argument.
"""
