"""Learned policies and their checkpoint folders.

A checkpoint folder holds `model.safetensors` (weights and normalisation buffers), `config.json`
(the architecture and the training settings) and `dataset.json` (what it was trained on);
`policies.checkpoint.load(path)` rebuilds the policy from it. `policies.folder` names those files
and imports no torch.
"""
