"""tacrom's reduced-order model: data loading, autoencoder, training and ONNX export."""
