"""The herd model of Schwager, Anderson and Rus (2007): basis, interaction laws, regressors,
model file."""
