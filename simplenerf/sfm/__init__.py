"""Structure from motion with pycolmap: sparse depth of posed views (DS-NeRF's prior) and own photos -> a scene."""
