"""ICESat-2 products, reader and writer: ATL03, ATL06, ATL07, classification, retrieval and the first-photon-bias correction. Pure at import."""
