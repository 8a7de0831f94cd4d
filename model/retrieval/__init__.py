"""Retrieval: motion databases of real capture that a bundle carries, and motion matching over them."""
