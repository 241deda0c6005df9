"""The pivotd serial protocol: codec, reference device model, test vectors (see PROTOCOL.md)."""
