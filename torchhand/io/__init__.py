"""Result files: the one reader of the result format (docs/result_format.md) and the digest that byte-identity is
checked with.

Modules
    ``result``  :func:`load_result`, :class:`Result`, :class:`Solution`
    ``digest``  :func:`solutions_digest`: one SHA-256 over a result's solution arrays

Atomic writes and npz reading, used by every layer, are the private :mod:`torchhand._atomic` and
:mod:`torchhand._npz` (docs/architecture.md).
"""
