"""The order of training: which samples make each global batch, as a pure function of the step.

:class:`OrderSampler` draws epoch permutations from ``(seed, epoch)`` (so an exact resume needs only
the step) and, with ``TrainConfig.ref_group`` > 1, keeps ``k`` samples of one reference window
together (:func:`reference_groups`), so the reference is encoded once for ``k`` targets.
"""

from __future__ import annotations

import numpy as np
from torch.utils.data import Dataset, Subset

from mer_data.base.errors import ConfigError

__all__ = ["OrderSampler", "reference_groups"]


class OrderSampler:
    """Global batches of indices from step ``start`` on: epoch ``e`` is the permutation drawn from
    (seed, e), cut into ``n // batch`` batches (the remainder is dropped); this rank takes every
    ``world``-th index of each batch. A pure function of the step, so resuming needs only the step.

    With ``groups`` (the sample indices of each reference window) and ``group`` = k > 1
    (``TrainConfig.ref_group``), epoch ``e`` permutes each window's samples and cuts them into
    chunks of k (a remainder of fewer than k sits the epoch out), permutes the chunks and cuts them
    into batches of ``batch / k`` chunks; this rank takes every ``world``-th chunk of each batch.
    """

    def __init__(
        self, n: int, batch: int, seed: int, start: int, rank: int, world: int,
        groups: list[np.ndarray] | None = None, group: int = 1,
    ) -> None:  # fmt: skip
        if n < batch:
            raise ConfigError(
                f"the dataset has {n} samples, fewer than one batch of {batch}",
                element="train.batch_size",
                fix="use a smaller --batch-size or more data",
            )
        self.n, self.batch, self.seed, self.start, self.rank, self.world = n, batch, seed, start, rank, world
        self.group = group
        self.per_epoch = n // batch
        self._chunks: tuple[int, np.ndarray] | None = None  # (epoch, its chunks)
        if group > 1:
            if groups is None:
                raise ValueError("group > 1 needs the groups")
            if (batch // group) % world:
                raise ConfigError(
                    f"{batch // group} windows per batch (batch_size {batch} / ref_group {group}) do not split "
                    f"evenly across {world} processes",
                    element="train.ref_group",
                    fix="choose batch_size / ref_group divisible by the number of processes",
                )
            self.groups = [np.asarray(g, dtype=np.int64) for g in groups]
            self.per_epoch = sum(len(g) // group for g in self.groups) // (batch // group)
            if self.per_epoch == 0:
                raise ConfigError(
                    f"no batch of {batch // group} windows with {group} samples each: the dataset's windows "
                    f"have {max((len(g) for g in self.groups), default=0)} samples at most",
                    element="train.ref_group",
                    fix="use a smaller ref_group or batch_size",
                )

    def _epoch_chunks(self, epoch: int, rng: np.random.Generator) -> np.ndarray:
        """(chunks, group) sample indices of one epoch, in its order."""
        if self._chunks is None or self._chunks[0] != epoch:
            k = self.group
            parts = [rng.permutation(g)[: len(g) // k * k].reshape(-1, k) for g in self.groups]
            chunks = np.concatenate(parts)
            self._chunks = (epoch, chunks[rng.permutation(len(chunks))])
        return self._chunks[1]

    def batch_at(self, step: int) -> list[int]:
        """This rank's sample indices of global batch ``step``."""
        epoch, k = divmod(step, self.per_epoch)
        rng = np.random.default_rng([self.seed, epoch])
        if self.group == 1:
            idx = rng.permutation(self.n)[k * self.batch : (k + 1) * self.batch]
            return [int(i) for i in idx[self.rank :: self.world]]
        per = self.batch // self.group
        chunks = self._epoch_chunks(epoch, rng)[k * per : (k + 1) * per]
        return [int(i) for i in chunks[self.rank :: self.world].reshape(-1)]

    def __iter__(self):
        step = self.start
        while True:
            yield self.batch_at(step)
            step += 1


def reference_groups(dataset: Dataset) -> list[np.ndarray]:
    """The sample indices of ``dataset`` that share one reference window, per window
    (:meth:`mer_data.shards.ShardDataset.reference_groups`; a ``Subset`` of one keeps its own)."""
    if hasattr(dataset, "reference_groups"):
        return dataset.reference_groups()
    if isinstance(dataset, Subset) and hasattr(dataset.dataset, "reference_groups"):
        pos = {int(i): p for p, i in enumerate(dataset.indices)}
        groups = [np.array([pos[int(i)] for i in g if int(i) in pos], dtype=np.int64) for g in dataset.dataset.reference_groups()]
        return [g for g in groups if len(g)]
    raise ConfigError(
        f"train.ref_group > 1 needs a dataset that knows which samples share a reference window; "
        f"{type(dataset).__name__} does not",
        element="train.ref_group",
        fix="train on a ShardDataset (or a Subset of one), or set ref_group to 1",
    )
