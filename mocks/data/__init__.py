"""Data files of the mocks (the packaged building, building.json); a package so that wheels include them."""
