"""Characters drawn in layers: parts posed by one set of handles."""

from ._character import Character as Character, CharacterRenderer as CharacterRenderer
from ._layers import Layer as Layer, load_layers as load_layers
