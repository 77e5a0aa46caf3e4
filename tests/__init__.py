"""skyfix's tests, in area folders mirroring src/skyfix/ (a package, so that files in different
folders may share a name)."""
