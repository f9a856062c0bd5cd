"""Registering people's own clouds: normalisation, the network, file formats, normal estimation."""
