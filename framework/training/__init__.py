"""What the first-frame fit and every dynamics method share: the training driver (:mod:`.loop`), the
Gaussian model and its learning rates, losses, backdrops, supersampling. Public for plugins."""
