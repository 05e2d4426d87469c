"""mvcjax: fast, differentiable 2D shape deformation with mean value coordinates.

What a user poses, renders, exports and fits with (`__all__`); the rig's parts, the
options that only studies of the method need and the extension points are in
`mvcjax.advanced`.
"""

import lazy_loader

__version__ = "0.1.0"

# Each name is imported where it is first used: `import mvcjax` and `mvcjax --help` do
# not wait for JAX. The names are in __init__.pyi.
_lazy_attribute, __dir__, __all__ = lazy_loader.attach_stub(__name__, __file__)


def __getattr__(name: str):
    """The name, imported on first use; a name of `mvcjax.advanced` asked for here says
    where it is."""
    if name in __all__:
        return _lazy_attribute(name)
    if not name.startswith("_") and hasattr(_lazy_attribute("advanced"), name):
        raise AttributeError(f"mvcjax.{name} is in mvcjax.advanced: write "
                             f"mvcjax.advanced.{name}.")
    raise AttributeError(f"module 'mvcjax' has no attribute {name!r}")
