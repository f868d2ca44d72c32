"""Pure numpy geometry: rigid transforms, rotations, rigid fits, ray casting."""
