//! Dataset building: simulate flights, attack GPS, run the EKF and collect labelled residues, split by flight, cached on disk.
