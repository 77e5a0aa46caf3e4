"""What identification builds from the catalogue: the pattern database and its bands, the 4-star
hash, the pair and triangle tables, and the named data the kernels take (the first layer of
:mod:`skyfix.identify`; it imports nothing of the layers above)."""
