// Placeholder: being implemented.
namespace sope {}
