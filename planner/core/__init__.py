"""The ground floor, imported by every room and importing none of them.

The exception tree, boundary value types (pose, quaternion, finite numbers), array aliases, SO(3)
helpers, the robot description schema, provenance hashes and the cache folder.
"""
