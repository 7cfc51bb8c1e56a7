%% @doc Internal. The BIL descriptions the simulated Avatars send: loaded
%% from the examples of the bil application, renamed per robot (robot N >= 2
%% gets EntityID lego-nxt-0N and ComponentIDs with the suffix -N) and cut to
%% the components of one smart-home gateway.
-module(avatar_sim_desc).

-export([example/1, robot/2, robot_entity/1, robot_component/2, subset/3, without/2,
         component_ids/1, feedback_category/2, consumes_type/3]).

%% @doc Parses an example description of the bil application.
-spec example(string()) -> bil:description().
example(File) ->
    Path = filename:join([code:priv_dir(bil), "examples", File]),
    {ok, Xml} = file:read_file(Path),
    {ok, Description} = bil:parse_description(Xml),
    Description.

%% @doc The description of robot `N', derived from lego_robot.xml (`Base').
-spec robot(pos_integer(), bil:description()) -> bil:description().
robot(1, Base) ->
    Base#{entity_id := robot_entity(1)};
robot(N, #{components := Components} = Base) ->
    Base#{entity_id := robot_entity(N),
          components := [C#{id := robot_component(N, Id)} || #{id := Id} = C <- Components]}.

-spec robot_entity(pos_integer()) -> binary().
robot_entity(N) -> list_to_binary(io_lib:format("lego-nxt-~2..0B", [N])).

%% @doc The ComponentID of robot `N' for a component of lego_robot.xml.
-spec robot_component(pos_integer(), binary()) -> binary().
robot_component(1, Id) -> Id;
robot_component(N, Id) -> <<Id/binary, "-", (integer_to_binary(N))/binary>>.

%% @doc The description restricted to `Components' (or all), with `EntityId'.
-spec subset(bil:description(), all | [binary()], binary()) -> bil:description().
subset(Description, all, EntityId) ->
    Description#{entity_id := EntityId};
subset(#{components := Cs} = Description, Ids, EntityId) ->
    Description#{entity_id := EntityId,
                 components := [C || #{id := Id} = C <- Cs, lists:member(Id, Ids)]}.

%% @doc The description without the components `Ids'.
-spec without(bil:description(), [binary()]) -> bil:description().
without(#{components := Cs} = Description, Ids) ->
    Description#{components := [C || #{id := Id} = C <- Cs, not lists:member(Id, Ids)]}.

-spec component_ids(bil:description()) -> [binary()].
component_ids(#{components := Cs}) -> [Id || #{id := Id} <- Cs].

%% @doc The category of a component's ACTION FEEDBACK consumer, which its
%% answers carry; `Default' for a component without one (sensors).
-spec feedback_category(bil:description(), binary()) -> binary() | undefined.
feedback_category(#{components := Cs}, Id) ->
    case [Cat || #{id := I, consumes := Es} <- Cs, I =:= Id,
                 #{category := Cat, type := T} <- Es, keyword(T) =:= <<"actionfeedback">>] of
        [Cat | _] -> Cat;
        [] -> undefined
    end.

%% @doc The ServiceType of a component's Consumes entry whose keyword is
%% `Keyword' (as written in the description), or `undefined'.
-spec consumes_type(bil:description(), binary(), binary()) -> binary() | undefined.
consumes_type(#{components := Cs}, Id, Keyword) ->
    case [T || #{id := I, consumes := Es} <- Cs, I =:= Id,
               #{type := T} <- Es, keyword(T) =:= Keyword] of
        [T | _] -> T;
        [] -> undefined
    end.

%% ASCII form of docs/bil.md's keyword rule: enough for the names of the
%% examples, which are all ASCII.
keyword(Bin) ->
    << <<(string:to_lower(C))>> || <<C>> <= Bin, is_alnum(C) >>.

is_alnum(C) -> (C >= $a andalso C =< $z) orelse (C >= $A andalso C =< $Z)
                   orelse (C >= $0 andalso C =< $9).
