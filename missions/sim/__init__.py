"""Synthetic underwater cave missions (``poseidon sim``)."""
