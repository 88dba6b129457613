"""The Duckietown domain: maps, lane geometry, dynamics, camera renderer and Gymnasium envs."""
