"""The visual-audio representation (VAR): encoders that put camera images and sound commands on one sphere.

Modules: `model` (encoders), `loss` (triplet loss), `dataset` (triplet collection and sound draws), `train`
(the one training entry point, for pre-training and fine-tuning), `finetune` (its fine-tuning defaults),
`image_augment`, `evaluate`, `plot`, `checkpoint`, `reward` (the intrinsic reward), `cli` (`varbot var ...`).
"""
