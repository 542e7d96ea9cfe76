"""Reference cabin meshes and the script that generates them (see README.md)."""
