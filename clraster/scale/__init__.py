"""Many views and many machines: a list of views rendered into files (`batch`), the same on
a Dask cluster and sort-last rendering of one view split over machines (`distributed`), and
the exact compositing of partial frames (`composite`)."""
