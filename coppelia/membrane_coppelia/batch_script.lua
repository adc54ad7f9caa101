-- Installed into the CoppeliaSim scene by membrane_coppelia.lattice (a customization script).
-- It moves the whole sphere lattice in one remote call per simulation step, instead of one
-- sim.setObjectPosition call per sphere.
local sim = require('sim')

function sysCall_init()
end

-- Move handles[i] to (xyz[3i-2], xyz[3i-1], xyz[3i]), given relative to the object `frame`
-- (sim.handle_world for world coordinates). Returns how many objects were moved.
function membraneSetPositions(handles, xyz, frame)
    local count = #handles
    if #xyz ~= 3 * count then
        error(string.format('membraneSetPositions: %d handles need %d coordinates, got %d',
            count, 3 * count, #xyz))
    end
    frame = frame or sim.handle_world
    for i = 1, count do
        local k = 3 * (i - 1)
        sim.setObjectPosition(handles[i], {xyz[k + 1], xyz[k + 2], xyz[k + 3]}, frame)
    end
    return count
end
