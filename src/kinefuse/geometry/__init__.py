"""Pure numpy geometry: rigid transforms, rotations, rigid fits, ray casting.

Pure numpy geometry: rigid transforms (``A2B`` naming), Kabsch, plane fits, ray casting, and the
one home of rotations. May import only errors and io (base).
"""
