"""A word-level prompt tokenizer built in place, for policies made from configuration alone.

Prompts here are short and drawn from a small vocabulary ("stack the blue cube on the green
cube"), so words are the meaningful units and an unknown word maps to ``[UNK]`` rather than to
noise. The tiny SmolVLA, the learned policy's CLIP text encoder and the offline pi0.5 each save
one beside their weights, so nothing is downloaded.
"""
from __future__ import annotations

from typing import Any, Sequence


def word_level_tokenizer(vocabulary: Sequence[str], **special: Any) -> Any:
    """A ``PreTrainedTokenizerFast`` giving each entry of ``vocabulary`` (special tokens first,
    then words) its index, lower-casing and splitting on white space, unknown words to ``[UNK]``
    (which ``vocabulary`` must hold); ``special`` are the tokenizer's keywords (``pad_token``...)."""
    from tokenizers import Tokenizer, normalizers, pre_tokenizers
    from tokenizers.models import WordLevel
    from transformers import PreTrainedTokenizerFast

    vocab = {token: index for index, token in enumerate(dict.fromkeys(vocabulary))}
    core = Tokenizer(WordLevel(vocab, unk_token="[UNK]"))
    core.normalizer = normalizers.Lowercase()
    core.pre_tokenizer = pre_tokenizers.Whitespace()
    return PreTrainedTokenizerFast(tokenizer_object=core, unk_token="[UNK]", **special)
