"""The files a scene file loads besides itself, as trimesh reads them.

A ``.gltf`` names its buffers and images, an ``.obj`` its ``.mtl`` files and they their textures;
each changes what is rendered, so each belongs to the world's identity. Which ones a file names
is the loader's business: rather than parse the formats here, the loader is handed a resolver
that notes every name it asks for. Imported only when a scene file is loaded (trimesh takes
0.6 s to import).
"""

from __future__ import annotations

import hashlib

from trimesh.resolvers import FilePathResolver


class CompanionResolver(FilePathResolver):
    """trimesh's resolver of a scene file's companions, noting each one asked for.

    :attr:`read` maps each name, as the scene file writes it (relative to its folder), to the
    SHA-256 of the bytes handed to the loader, or None where there was no such file (an ``.obj``
    loads without its ``.mtl``: the file appearing later changes the world).
    """

    def __init__(self, scene_path: str) -> None:
        super().__init__(scene_path)
        self.read: dict[str, str | None] = {}

    def get(self, name: str) -> bytes:
        try:
            data = super().get(name)
        except (OSError, ValueError):  # missing, unreadable, or outside the scene's folder
            self.read[name] = None
            raise
        self.read[name] = hashlib.sha256(data).hexdigest()
        return data
