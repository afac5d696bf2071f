"""Real hardware behind the instrument interface: transports, Dynamixel arms, Modbus stages,
serial spectrometers, goniometer kinematics and safety limits."""
