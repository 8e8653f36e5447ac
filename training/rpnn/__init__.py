"""Kallweit et al. 2017 RPNN: network, record reader, ONNX export."""
