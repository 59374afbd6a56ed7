//! Reading and writing images: EXR, PNG, PFM. (Being written.)
