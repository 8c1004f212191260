"""Contact-sampling synthesis of finger motion (Ye & Liu 2012): search state, node tests, the randomized search,
reconstruction of smooth motion and the result files."""
