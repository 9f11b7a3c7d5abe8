"""What a stored result is and where it lives: the folder layout and labels (:mod:`.layout`),
the identity a row carries and how two identities differ (:mod:`.identity`), the code
fingerprints the identity holds (:mod:`.fingerprint`), and whose a row is (:mod:`.ownership`).
It imports protocol and core, and no code that computes a number."""
