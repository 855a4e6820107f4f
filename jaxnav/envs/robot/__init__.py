"""The continuous robot navigation environments (the paper's maze experiment, Sec. IV-B):
maze layouts (``mazes``), geometry (``geometry``) and the environments built on them."""
