"""Device drivers: one module per instrument family, each speaking its real protocol."""
