"""Model file formats of other tools, read and written next to fixer4d's own (``fixer4d.model.io``).

ply3dgs: the INRIA 3DGS PLY of static Gaussians (one frame of a spacetime model; reading one).
ply_sequence: a folder of per-frame 3DGS PLYs plus manifest.json.
stgs_reference: PLYs written by SpacetimeGaussians' lite model.
foreign: which of those a PLY without fixer4d's header is, or a clear refusal.
splatv: splaTV's single-file dynamic format (byte layout, encode/decode).
"""
