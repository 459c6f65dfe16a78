namespace sope {}
